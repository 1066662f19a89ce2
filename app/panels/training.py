"""Training: start/pause/resume, lambda_gen and K (stage 2), step, Gaussian count, losses
plotted with implot. Training runs in its own thread and yields to the UI's frames."""
from __future__ import annotations

import numpy as np
from imgui_bundle import imgui, implot

from app.panels._layout import panel

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
            imgui.text(f"state: {tr.state}   step {tr.step}")
            if tr.error:
                imgui.text_colored(imgui.ImVec4(1.0, 0.35, 0.3, 1.0), tr.error)
            if tr.state in ("idle",) and imgui.button("start"):
                tr.start()
            if tr.state in ("running", "setup") and imgui.button("pause"):
                tr.pause()
            if tr.state == "paused" and imgui.button("resume"):
                tr.resume()
            g = viewer.state.gaussians
            imgui.text(f"Gaussians: {0 if g is None else g.n}   step time {1e3 * tr.step_seconds:.0f} ms")
            st2 = getattr(tr.trainer, "stage2", None)
            if st2 is not None:
                changed, lam = imgui.slider_float("lambda_gen", float(st2.lambda_gen), 0.0, 2.0)
                if changed:
                    tr.set_stage2(lambda_gen=lam)
                changed, k = imgui.input_int("K (refresh every)", int(st2.refresh_every))
                if changed and k > 0:
                    tr.set_stage2(refresh_every=k)
            hist = tr.losses()
            if hist:
                last = hist[-1]
                imgui.text(f"loss {last.get('loss', float('nan')):.4f}   psnr {last.get('psnr', float('nan')):.2f} dB")
                stride = max(1, len(hist) // PLOT_POINTS)
                rows = hist[::stride]
                steps = np.array([r.get("step", i * stride) for i, r in enumerate(rows)], np.float64)
                if implot.begin_plot("losses", imgui.ImVec2(-1, 170)):
                    implot.setup_axes("step", "loss", implot.AxisFlags_.auto_fit.value, implot.AxisFlags_.auto_fit.value)
                    for key in ("loss", "loss_stg", "loss_gen"):
                        ys = np.array([r.get(key, np.nan) for r in rows], np.float64)
                        if np.isfinite(ys).any():
                            implot.plot_line(key, steps, ys)
                    implot.end_plot()
