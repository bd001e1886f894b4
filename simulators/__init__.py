"""Simulated hardware behind the same interfaces as :mod:`drivers`.

The stage simulator speaks the same bytes on the wire as a Zaber stage; the camera simulator
renders a zebrafish-like phantom at the stage's *actual* angle through a rig geometry whose
truth the pipeline is never told. Simulators never import the pipeline stages.
"""
