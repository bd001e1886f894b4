"""The shipped rig descriptions (YAML), installed as the package data of ``vastcal.rig_configs``.

The repository keeps them in the top-level ``config/`` folder; ``pyproject.toml`` maps that folder to
``vastcal.rig_configs`` so that an installed vastcal finds them with :mod:`importlib.resources`
(:data:`vastcal.config.CONFIG_DIR`). This file holds no code.
"""
