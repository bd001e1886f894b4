"""The one exception tree of vastcal, its drivers and its simulators.

Every error that vastcal raises on purpose derives from :class:`VastcalError` *and*
from the builtin that best describes it, so callers may catch either
(``except TimeoutError`` works for a stage that stopped answering).

The command line turns any :class:`VastcalError` into one line on stderr and the
exit code given by :attr:`VastcalError.exit_code`; anything else also ends in one line
(exit 1; ``-v`` shows its traceback).

Exit codes (one table for every command; :data:`EXIT_CODES`)::

    0    ok
    1    failure: the work could not be done (device fault, analysis failed, disk full, a bug)
    2    bad input: arguments, rig file, image folder, a damaged or foreign session; existing output without --force
    3    incomplete: the session (or the work) is incomplete (``info`` on an aborted session, a stage
         refused because the session lacks frames)
    4    measured, but the quality verdict is ``fail``: the numbers are stored and reported, and must not be
         used as they are (``check`` exits 0 and prints its verdict line on stderr)
    130  interrupted by Ctrl-C (SIGINT), in every phase of every command
    128+N  stopped by another signal N (SIGTERM 143, SIGHUP 129): kept as a shell reports it, so a batch
         scheduler or a service manager can tell its own kill from the operator's Ctrl-C

Tree::

    VastcalError
    ├── UserInputError                 bad input from a user: exit code 2
    │   ├── ConfigError(ValueError)    rig YAML unreadable, unknown key, wrong type, out of range
    │   ├── ImportDataError(ValueError)image folder / camera file that cannot be imported
    │   ├── ImplausibleValueError(ValueError) a pixel size, angle list or voxel size no instrument gives
    │   └── OutputExistsError(FileExistsError) refusing to overwrite without --force
    ├── SessionError                   a session file that is not ours or is damaged
    │   ├── NotASessionError(ValueError)   not HDF5, truncated, or written by another program: exit code 2
    │   ├── SessionIncompleteError         frames missing / acquisition did not finish: exit code 3
    │   ├── SessionBusyError(BlockingIOError) another process is writing the same file
    │   └── SessionCorruptError            a stored frame does not match its checksum: exit code 2
    ├── DeviceError                    hardware (or simulated hardware) misbehaved
    │   ├── DeviceTimeoutError(TimeoutError)  no (complete) answer within the finite wait
    │   ├── ProtocolError(IOError)     garbage, wrong checksum, reply that does not parse
    │   ├── CommandRejectedError       the device answered RJ <reason>
    │   ├── StageFaultError            a fault flag (F…) after a move, e.g. FS stall
    │   ├── PositionMismatchError      the read-back position differs from the target
    │   ├── NotHomedError              WR/WH: home the stage first
    │   ├── DeviceDisconnectedError(ConnectionError) the port went away
    │   └── CameraError                the camera refused a setting or delivered nothing
    ├── AcquisitionAborted             the operator pressed Ctrl-C (exit status "abort")
    └── AnalysisError(ValueError)      calibration / reconstruction cannot proceed on this data
        ├── ColourModelError           foreground and background cannot be separated
        ├── EmptyHullError             every voxel was carved away
        └── MissingStageError          a later stage needs an earlier one ("run vastcal calibrate")
"""

from __future__ import annotations

EXIT_OK = 0
"""The command did what was asked."""
EXIT_FAILURE = 1
"""The work could not be done (a device fault, an analysis that cannot proceed, resources, a bug)."""
EXIT_BAD_INPUT = 2
"""Bad input: arguments, configuration, images, a damaged session, an existing output without ``--force``."""
EXIT_INCOMPLETE = 3
"""The session (or the work) is incomplete."""
EXIT_QC_FAIL = 4
"""The measurement was made and stored, but its quality verdict is ``fail`` (a script must not use its numbers)."""
EXIT_INTERRUPTED = 130
"""Interrupted by Ctrl-C (128 + SIGINT)."""

EXIT_CODES: dict[int, str] = {
    EXIT_OK: "ok",
    EXIT_FAILURE: "failure",
    EXIT_BAD_INPUT: "bad input (arguments, files, existing output without --force)",
    EXIT_INCOMPLETE: "incomplete (session or work)",
    EXIT_QC_FAIL: "measured, but the quality verdict is fail (results stored; 'check' exits 0, verdict on stderr)",
    EXIT_INTERRUPTED: "interrupted (Ctrl-C); another stop signal N gives 128+N (SIGTERM 143, SIGHUP 129)",
}
"""The exit-code table every command follows (printed in ``vastcal --help``)."""


class VastcalError(Exception):
    """Base of every error vastcal raises on purpose.

    ``exit_code`` is what the command line exits with when this error ends a command.
    """

    exit_code: int = EXIT_FAILURE

    def about(self, source: object) -> VastcalError:
        """The same error, its message prefixed with ``source`` (e.g. the session file) unless it names it.

        For errors raised deep in pure functions of arrays, re-raised where the file is known::

            except VastcalError as exc:
                raise exc.about(path) from None
        """
        text = str(self)
        if str(source) in text:
            return self
        try:
            new = type(self)(f"{source}: {text}")
        except TypeError:  # a subclass with its own constructor: keep it as it is
            return self
        new.__dict__.update(self.__dict__)
        return new


class UserInputError(VastcalError):
    """The user gave input that cannot be used (raised before anything is written)."""

    exit_code = EXIT_BAD_INPUT


class ConfigError(UserInputError, ValueError):
    """The rig configuration is unreadable or invalid.

    The message names the file, the key path (``camera.exposure_us``) and what was expected.
    """


class ImportDataError(UserInputError, ValueError):
    """An image folder, mask folder, angle file or camera file cannot be imported."""


class ImplausibleValueError(UserInputError, ValueError):
    """A value whose unit is most likely wrong: a pixel size, an angle list or a voxel size outside what any
    instrument or protocol gives (:mod:`vastcal.plausibility`). The message names the value, where it came from and
    the likely fix; ``--accept-units`` uses the value as it is."""


class OutputExistsError(UserInputError, FileExistsError):
    """The output file exists and ``--force`` was not given; nothing was written."""


class SessionError(VastcalError):
    """A session file cannot be used."""


class NotASessionError(SessionError, ValueError):
    """The file is not HDF5, is truncated, or is an HDF5 file that vastcal did not write."""

    exit_code = EXIT_BAD_INPUT


class SessionIncompleteError(SessionError):
    """The session lacks frames or metadata a stage needs (e.g. acquisition was interrupted)."""

    exit_code = EXIT_INCOMPLETE


class SessionBusyError(SessionError, BlockingIOError):
    """Another process holds the write lock of this session (or of its results file)."""


class SessionCorruptError(SessionError):
    """A committed frame no longer matches the CRC-32 recorded when it was written."""

    exit_code = EXIT_BAD_INPUT


class DeviceError(VastcalError):
    """A device (real or simulated) misbehaved."""


class DeviceTimeoutError(DeviceError, TimeoutError):
    """No complete reply or frame arrived within the finite timeout."""


class ProtocolError(DeviceError, IOError):
    """The device answered bytes that do not parse as the expected protocol."""


class CommandRejectedError(DeviceError):
    """The device rejected a command; :attr:`reason` holds its word verbatim (e.g. ``BADDATA``)."""

    def __init__(self, message: str, reason: str = "") -> None:
        super().__init__(message)
        self.reason = reason


class StageFaultError(DeviceError):
    """The stage reports a fault flag (``F…``) after a move; :attr:`flag` holds it (e.g. ``FS``)."""

    def __init__(self, message: str, flag: str = "") -> None:
        super().__init__(message)
        self.flag = flag


class PositionMismatchError(DeviceError):
    """After a move the read-back position differs from the target by more than the tolerance."""


class NotHomedError(DeviceError):
    """The stage has no reference position (``WR``/``WH``): home it before absolute moves."""


class DeviceDisconnectedError(DeviceError, ConnectionError):
    """The port or camera went away."""


class CameraError(DeviceError):
    """The camera refused a setting, or delivered an unusable frame."""


class AcquisitionAborted(VastcalError):
    """The operator cancelled the acquisition (Ctrl-C); the session is closed with status abort."""

    exit_code = EXIT_INTERRUPTED


class AnalysisError(VastcalError, ValueError):
    """Calibration, reconstruction or measurement cannot proceed on this data."""


class ColourModelError(AnalysisError):
    """The foreground and background colour models cannot be learned or do not separate."""


class EmptyHullError(AnalysisError):
    """The visual hull is empty: the cameras or the silhouettes are inconsistent."""


class MissingStageError(AnalysisError):
    """A stage needs the result of an earlier one; the message says which command to run."""
