"""The exception tree. Every error the user can cause derives from :class:`KinefuseError`.

Messages say what was expected, what came, and what to do.
"""


class KinefuseError(Exception):
    """Base class of all kinefuse errors."""


class InputError(KinefuseError, ValueError):
    """A file, array or argument that the caller supplied is malformed."""


class MotionFormatError(InputError):
    """A motion file (BVH, ASF/AMC, ...) could not be parsed.

    ``path`` and ``line`` (1-based, when known) say where the parser choked.
    """

    def __init__(self, message: str, *, path: str | None = None, line: int | None = None):
        where = ""
        if path is not None:
            where = f"{path}"
            if line is not None:
                where += f":{line}"
            where += ": "
        super().__init__(where + message)
        self.path = path
        self.line = line


class RetargetError(InputError):
    """A source skeleton could not be mapped onto the Kinect v2 joints."""


class RigError(InputError):
    """A rig file (sensor layout) is malformed."""


class StoreError(KinefuseError):
    """A session store is missing, of the wrong schema version, or lacks a table that is needed."""


class CalibrationError(KinefuseError):
    """Sensor poses could not be estimated."""


class CalibrationFailed(CalibrationError):
    """The calibration ran on the session's data and could not register the sensors (the
    commands exit with 3, as for a calibration graded failed)."""


class FusionError(KinefuseError):
    """Joint observations could not be fused."""


class SyncError(KinefuseError):
    """Clocks could not be synchronized."""


class ProtocolError(KinefuseError):
    """A network peer sent something that breaks the wire protocol."""


class OutputError(KinefuseError):
    """An output file or folder could not be written, or would replace a file kinefuse did not
    make. The message names the path and the reason; nothing already there was changed."""


class IncompleteSessionError(StoreError):
    """A session store was not completed (an interrupted recording or simulation)."""
