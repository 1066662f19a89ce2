"""Training: start/pause/resume, lambda_gen and K (stage 2), step, Gaussian count, losses
plotted with implot. Training runs in its own thread and yields to the UI's frames."""
from __future__ import annotations

import time

import numpy as np
from imgui_bundle import imgui, implot

from app.panels._layout import error_text, leave_room_for_label, one_line, panel, tip

# Loss curves drawn from at most this many points (the history is decimated to it).
PLOT_POINTS = 2000


def draw(viewer) -> None:
    tr = viewer.source.training
    with panel(viewer, "training", "Training", 1105, 30, 330, 330) as expanded:
        if not expanded:
            return
        if tr is None:
            imgui.text_wrapped("Showing a saved model. Open a scene (fixer4d-view SCENE) to train live.")
        else:
            # the controls first, on lines that stay: the state and progress lines under them
            # come and go (setup, errors) without moving a control under the pointer
            total = tr.total_steps
            control = {"idle": ("start", tr.start, "start training in the background"),
                       "running": ("pause", tr.pause, "pause training after the current step (the model shown stays)"),
                       "setup": ("pause", tr.pause, "pause training once it is set up"),
                       "paused": ("resume", tr.resume, "go on training from this step")}.get(tr.state)
            if control is not None:
                clicked = imgui.button(control[0])
                viewer.record_item("training_control")
                tip(control[2], viewer)
                if clicked:
                    control[1]()
                imgui.same_line()
            imgui.align_text_to_frame_padding()  # the line is a button high with or without one
            one_line(tr.state, viewer, disabled=False)
            if total:
                imgui.progress_bar(min(tr.step / total, 1.0), imgui.ImVec2(-1, 0), f"step {tr.step} of {total}")
            else:  # (as high as the bar that replaces it once the trainer is set up)
                imgui.align_text_to_frame_padding()
                imgui.text(f"step {tr.step}")
            st2 = getattr(tr.trainer, "stage2", None)
            if st2 is not None:
                leave_room_for_label("lambda_gen")
                changed, lam = imgui.slider_float("lambda_gen", float(st2.lambda_gen), 0.0, 2.0)
                tip("weight of the pseudo-target loss against the real frames' loss (stage 2)", viewer)
                if changed:
                    tr.set_stage2(lambda_gen=lam)
                leave_room_for_label("K (refresh)")
                changed, k = imgui.input_int("K (refresh)", int(st2.refresh_every))
                tip("refresh the pseudo-targets every K steps (stage 2)", viewer)
                if changed and k > 0:
                    tr.set_stage2(refresh_every=k)
            if tr.state == "setup":
                elapsed = 0.0 if tr.setup_started is None else time.monotonic() - tr.setup_started
                imgui.text_wrapped(f"setting up ({elapsed:.0f} s): {tr.setup_status or 'starting'}")
            if tr.error:
                error_text(tr.error)
            g = viewer.state.gaussians
            rate, eta = tr.steps_per_s, tr.eta_s
            imgui.text_wrapped(f"Gaussians: {0 if g is None else g.n}   {rate:.2f} steps/s" if rate else
                               f"Gaussians: {0 if g is None else g.n}")
            if eta is not None and tr.state == "running":
                imgui.text_wrapped(f"step time {1e3 * tr.step_seconds:.0f} ms   ETA {format_duration(eta)}")
            hist = tr.losses()
            if hist:
                last = hist[-1]
                imgui.text_wrapped(f"loss {last.get('loss', float('nan')):.4f}   "
                                   f"psnr {last.get('psnr', float('nan')):.2f} dB")
                stride = max(1, len(hist) // PLOT_POINTS)
                rows = hist[::stride]
                steps = np.array([r.get("step", i * stride) for i, r in enumerate(rows)], np.float64)
                series = plotted_series(rows)
                if series and implot.begin_plot("losses", imgui.ImVec2(-1, 170)):
                    implot.setup_axes("step", "loss", implot.AxisFlags_.auto_fit.value, implot.AxisFlags_.auto_fit.value)
                    for key, ys in series.items():
                        implot.plot_line(key, steps, ys)
                    implot.end_plot()


# Loss terms the trainer may record, in legend order.
LOSS_KEYS = ("loss", "loss_stg", "loss_gen")


def plotted_series(rows: list[dict]) -> dict[str, np.ndarray]:
    """The loss curves worth a line: terms with finite non-zero values (stage 1 records
    loss_gen = 0), leaving out one that repeats an earlier curve exactly (stage 1's loss is its
    loss_stg)."""
    out: dict[str, np.ndarray] = {}
    for key in LOSS_KEYS:
        ys = np.array([r.get(key, np.nan) for r in rows], np.float64)
        finite = ys[np.isfinite(ys)]
        if not finite.size or not np.any(finite):  # absent, or recorded as 0 (no such term now)
            continue
        if any(np.array_equal(ys, other, equal_nan=True) for other in out.values()):
            continue
        out[key] = ys
    return out


def format_duration(seconds: float) -> str:
    s = int(round(seconds))
    return f"{s // 3600}h {s % 3600 // 60:02d}m" if s >= 3600 else f"{s // 60}m {s % 60:02d}s"
