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


def file_system_problem(error: OSError) -> str | None:
    """One line naming the path a file-system call failed on and why; None when no path is involved.

    Tools print this instead of a traceback when an output folder lies under a file, a file cannot be read, a
    folder is not writable, or a disk is full; an ``OSError`` without a path (a socket, a signal) keeps its
    traceback.
    """
    if error.filename is None:
        return None
    import errno

    paths = f"{error.filename}" + (f" -> {error.filename2}" if error.filename2 is not None else "")
    if isinstance(error, FileExistsError | NotADirectoryError):
        reason = "a file stands where a folder is needed"
    elif isinstance(error, IsADirectoryError):
        reason = "a folder stands where a file is needed"
    elif isinstance(error, FileNotFoundError):
        reason = "not found"
    elif isinstance(error, PermissionError):
        reason = "no permission"
    elif error.errno == errno.ENOSPC:
        reason = "the disk is full"
    else:
        reason = error.strerror or type(error).__name__
    return f"{reason}: {paths}; check that path (and its permissions), or give another"
