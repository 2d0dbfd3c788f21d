"""The one exception the reconstruction raises for a frame it cannot reconstruct."""
from __future__ import annotations

__all__ = ["FrameError"]


class FrameError(ValueError):
    """A frame (or pair of frames) that cannot be reconstructed.

    The message is a single line giving the reason, prefixed with the camera
    name when one camera is to blame, e.g.
    ``"side: no silhouette (max difference 3 < 12 gray levels)"``. Callers log
    it as is and go on with the next frame, so it must read well on its own.

    Parameters
    ----------
    reason : str
        Why the frame cannot be reconstructed (one line; newlines are folded).
    camera : str, optional
        Name of the camera whose frame is at fault.

    Attributes
    ----------
    reason : str
        The reason without the camera prefix.
    camera : str or None
        The camera name, or ``None`` when no single camera is involved.
    """

    def __init__(self, reason: str, camera: str | None = None):
        # Folded to one line: messages go to one-line logs and status bars.
        reason = " ".join(str(reason).split())
        self.reason = reason
        self.camera = camera
        super().__init__(f"{camera}: {reason}" if camera else reason)
