"""`ndfa plant --log`: the frames before and after planting, side by side, in a Rerun file (.rrd).

Entities: `{session}/before/{color,depth}` and `{session}/after/{color,depth}`, on the `frame`
timeline (the frame index). Streamed to a hidden temporary beside the path and moved onto it on
`close` (`ndfa.io.atomic.Staged`); `abort` leaves the path as it was.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from ndfa.io.atomic import Staged


class PlantPreview:
    def __init__(self, path: Path, sessions: tuple[str, ...] = ("source", "target")) -> None:
        self.path = Path(path)
        self.rec = rr.RecordingStream("ndfa_plant")
        self._staged = Staged(self.path)
        self.rec.save(str(self._staged.temporary))
        rows = [rrb.Horizontal(*(rrb.Spatial2DView(origin=f"{session}/{when}", name=f"{session} {when}")
                                 for when in ("before", "after"))) for session in sessions]
        self.rec.send_blueprint(rrb.Blueprint(rrb.Vertical(*rows)), make_active=True, make_default=True)

    def log(self, session: str, index: int, before: tuple[np.ndarray | None, np.ndarray],
            after: tuple[np.ndarray | None, np.ndarray]) -> None:
        """One frame's (colour or None, depth in metres) before and after."""
        self.rec.set_time("frame", sequence=index)
        for when, (rgb, depth) in (("before", before), ("after", after)):
            if rgb is not None:
                self.rec.log(f"{session}/{when}/color", rr.Image(rgb))
            self.rec.log(f"{session}/{when}/depth", rr.DepthImage(depth, meter=1.0))

    def close(self) -> None:
        self.rec.flush()
        self.rec.disconnect()
        self._staged.commit()

    def abort(self) -> None:
        self.rec.disconnect()
        self._staged.discard()
