"""Errors a user can cause (bad path, existing output, unreadable file), each with a one-line message."""


class RecorderError(Exception):
    """A clear, one-line error naming the path involved; CLIs print it as `error: ...` and exit 2."""


class RecordingInterrupted(KeyboardInterrupt):
    """Raised by `Recorder.log_step` after a SIGTERM/SIGINT once the current step is safely recorded;
    `signum` is the signal's number."""

    def __init__(self, message: str, signum: int):
        super().__init__(message)
        self.signum = signum
