"""Error classes shared by every package: one base so tools can report any of them cleanly."""


class VesselError(Exception):
    """A problem with the user's input or set-up; the message names the problem and the fix.

    Command-line tools print it as one line and exit with status 2; nodes log it, count it and carry on
    (or refuse to start, when it concerns their configuration).
    """


class CalibrationError(VesselError):
    """Calibration input or a calibration file cannot be used."""


class DataError(VesselError):
    """A dataset, CSV, GPS or bag file is missing, malformed or inconsistent."""


class ModelError(VesselError):
    """A detector model is missing, corrupt or has an unsupported interface."""
