"""The progress bar of a flight, with the live figures a user watches (tqdm), or nothing."""

from __future__ import annotations


class Progress:
    """tqdm's bar with the splat count, feasible candidates and PSNRs of the last frame; inert when disabled."""

    def __init__(self, total: int, done: int, enabled: bool) -> None:
        self.bar = None
        if enabled:
            from tqdm import tqdm

            from flightrecon.metric_defs import METRICS

            self.bar = tqdm(total=total, initial=done, unit="frame", dynamic_ncols=True)
            self.psnr = METRICS["psnr"]

    def update(self, row: dict) -> None:
        """Advance by one frame, showing its row of frames.csv."""
        if self.bar is None:
            return
        post = {"splats": row.get("n_splats"), "feasible": row.get("n_feasible"),  # PSNRs blank where none
                "psnr": self.psnr.format(row.get("frame_psnr"), missing=""),
                "eval": self.psnr.format(row.get("eval_psnr"), missing="")}
        self.bar.set_postfix({k: v for k, v in post.items() if v not in (None, "")}, refresh=False)
        self.bar.update(1)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()
