"""``render_mode="human"``: a matplotlib window showing the network, updated in place.

Headless-safe: under a non-interactive matplotlib backend (``Agg``, the default on a machine
without a display, or ``MPLBACKEND=Agg``) the figure is drawn off-screen and nothing is shown,
nothing raises and nothing waits. Under an interactive backend (TkAgg, QtAgg, ...) the window
opens on the first frame and each later frame replaces the image (``plt.pause`` lets the GUI
draw it).
"""

from __future__ import annotations

from typing import Any

import numpy as np

# Backends that draw to files or memory only (matplotlib's own names, lower case).
_NON_INTERACTIVE = {"agg", "cairo", "pdf", "pgf", "ps", "svg", "template"}


def interactive_backend() -> bool:
    """Whether matplotlib's current backend can show a window."""
    import matplotlib

    backend = matplotlib.get_backend().lower()
    return backend not in _NON_INTERACTIVE and "inline" not in backend


class HumanViewer:
    """One matplotlib figure that shows RGB frames, created on the first :meth:`show`.

    Args:
        title: window title.
        fps: frames per second an interactive window paces itself to (``1 / fps`` s pause).
    """

    def __init__(self, title: str = "mivecc", fps: float = 10.0) -> None:
        self.title = title
        self.fps = fps
        self._fig: Any = None
        self._image: Any = None
        self.frames_shown = 0

    def show(self, frame: np.ndarray) -> None:
        """Display ``frame`` ((H, W, 3) uint8), replacing the previous one."""
        import matplotlib.pyplot as plt

        if self._fig is None or not plt.fignum_exists(self._fig.number):
            self._fig, ax = plt.subplots(num=self.title)
            ax.set_axis_off()
            self._image = ax.imshow(frame)
            self._fig.tight_layout()
        else:
            self._image.set_data(frame)
        self.frames_shown += 1
        if interactive_backend():
            plt.pause(1.0 / self.fps)  # shows the window and lets the GUI draw
        else:
            self._fig.canvas.draw()  # off-screen: keeps the figure current, shows nothing

    @property
    def figure(self) -> Any:
        """The matplotlib figure (``None`` before the first frame or after :meth:`close`)."""
        return self._fig

    def close(self) -> None:
        """Close the window (idempotent)."""
        if self._fig is not None:
            import matplotlib.pyplot as plt

            plt.close(self._fig)
            self._fig = self._image = None
