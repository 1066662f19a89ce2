"""Compare: for a trajectory frame of a cached restoration, the current render vs the cached
pseudo-target (and the ground truth where the scene has one: a real camera, or any camera of a
synthetic scene): side by side, split slider, A/B toggle, labels and per-frame PSNR. Where the
clip carries it, a fourth pane shows where the pseudo-target pulls the model towards the
restorer (magenta; ``supervision_map``) with its share of the frame."""
from __future__ import annotations

import time

import numpy as np
from imgui_bundle import imgui

from app.panels._layout import combo_fit, elide, leave_room_for_label, panel, same_line_if_fits, tip

# Re-list the cache at most this often (seconds): listing reads meta.json files from disk.
CACHE_POLL_S = 1.0
MODES = ("side by side", "split", "A/B")


def draw(viewer) -> None:
    src = viewer.source
    ui = viewer.__dict__.setdefault("_compare_ui", {"entries": [], "polled": -1e9, "entry": 0, "k": 0,
                                                    "mode": 0, "split": 0.5, "show_b": False, "cache": {}})
    with panel(viewer, "compare", "Compare", 300, 605, 800, 290) as expanded:
        if not expanded:
            return
        if src.cache is None:
            imgui.text_wrapped("No restoration cache (open a run folder or queue a restoration).")
        else:
            body(viewer, ui)


def refresh_entries(viewer, ui: dict) -> list:
    now = time.monotonic()
    if now - ui["polled"] > CACHE_POLL_S:
        src = viewer.source
        # a segmented run's clips live in its segments' run folders (the top-level cache holds the
        # viewer's own restorations of the whole clip)
        ui["entries"] = list(src.cache.entries()) + (src.segments.cache_entries() if src.segments is not None else [])
        ui["polled"] = now
    return ui["entries"]


def frame_images(viewer, ui: dict, entry, k: int) -> dict[str, np.ndarray]:
    """{"render", "target", optionally "truth"} (H, W, 3) float32 for frame k of ``entry``
    (cached per entry, frame and displayed model). The render is over the run's background, as
    the pseudo-targets were made, whatever the 3D view shows."""
    background = viewer.targets_background()
    key = (entry.key, entry.round, k, viewer.state.gaussians_version, background)
    cache = ui["cache"]
    if key not in cache:
        cam = entry.cameras[k]
        out = {"render": viewer.gaussians_render_fn(background)(cam, entry.time)["rgb"], "target": entry.rgb()[k]}
        weight = supervision_map(entry)
        if weight is not None:
            out["supervised"] = supervised_overlay(out["target"], weight[k])
            out["supervised_fraction"] = float(weight[k].mean())
        truth = ground_truth(viewer.source.scene, entry, cam)
        if truth is not None:
            out["truth"] = truth
        cache.clear()
        cache[key] = out
    return cache[key]


def supervision_map(entry) -> np.ndarray | None:
    """(F, H, W) in [0, 1] or None: what pulls the model towards the restorer in an entry. A gated
    pseudo-target (meta "pseudo_target": "gated") is the restored frame only where its stored
    confidence (the gate: holes, confident unobserved pixels) says so and the render elsewhere;
    another entry's pseudo-loss acts where the train cameras leave a pixel unobserved."""
    meta = getattr(entry, "meta", None) or {}
    if meta.get("pseudo_target") == "gated":
        return entry.confidence()
    return entry.unobserved() if hasattr(entry, "unobserved") else None


def supervised_overlay(target: np.ndarray, weight: np.ndarray) -> np.ndarray:
    """(H, W, 3): the pseudo-target dimmed, magenta in proportion to the pseudo-loss weight
    (``weight`` (H, W) in [0, 1], 1 = no train camera explains the pixel)."""
    w = np.clip(np.asarray(weight, np.float32), 0.0, 1.0)[..., None]
    magenta = np.array([1.0, 0.0, 1.0], np.float32)
    return (0.35 * target * (1.0 - w) + w * (0.4 * target + 0.6 * magenta)).astype(np.float32)


def ground_truth(scene, entry, cam) -> np.ndarray | None:
    if scene is None:
        return None
    for i, c in enumerate(scene.cameras):
        if c.width == cam.width and c.height == cam.height and np.allclose(c.c2w, cam.c2w, atol=1e-9) \
                and np.allclose(c.K, cam.K, atol=1e-9):
            return scene.frame(int(entry.frame), i)
    if hasattr(scene, "render_gt"):
        return scene.render_gt(cam, float(entry.time))[0]
    return None


def body(viewer, ui: dict) -> None:
    from fixer4d.eval.metrics import psnr

    entries = refresh_entries(viewer, ui)
    if not entries:
        imgui.text("the cache has no finished clips yet")
        return
    ui.setdefault("filter", "")
    imgui.set_next_item_width(min(120.0, imgui.get_content_region_avail().x))
    _, ui["filter"] = imgui.input_text_with_hint("##filter", "filter clips", ui["filter"])
    viewer.record_item("clip_filter")
    tip("show only the clips whose name (and round) contain every word typed here", viewer)
    words = ui["filter"].lower().split()
    shown = [e for e in entries if all(w in f"round {e.round} {e.key}".lower() for w in words)]
    if not shown:
        same_line_if_fits(imgui.calc_text_size("no clip matches (999 in the cache)").x)
        imgui.text(f"no clip matches ({len(entries)} in the cache)")
        return
    names = [f"round {e.round}  {e.key}" for e in shown]
    current = next((i for i, e in enumerate(shown) if (e.round, e.key) == ui.get("picked")), 0)
    clip_label = f"clip ({len(shown)}/{len(entries)})"
    same_line_if_fits(160.0)
    leave_room_for_label(clip_label)
    _, current = combo_fit(clip_label, current, names, "the cached restored clip to compare (round and cache key: "
                           "pair, frame, the viewer's trajectory settings)", viewer)
    entry = shown[current]
    ui["picked"] = (entry.round, entry.key)
    n = len(entry.cameras)
    ui["k"] = min(ui["k"], n - 1)
    leave_room_for_label("frame", at_most=150)
    _, ui["k"] = imgui.slider_int("frame", ui["k"], 0, n - 1)
    tip("the frame of the clip shown (its camera along the trajectory)", viewer)
    same_line_if_fits(120.0)
    leave_room_for_label("mode", at_most=120)
    _, ui["mode"] = combo_fit("mode", ui["mode"], list(MODES), "side by side: the images in a grid; split: render "
                              "left of the line, pseudo-target right; A/B: one at a time (B key switches)", viewer)
    imgs = frame_images(viewer, ui, entry, ui["k"])
    labels = [("render", "render (current model)"), ("target", "pseudo-target (cache)"), ("truth", "ground truth"),
              ("supervised", "where the target is restored (magenta)")]
    scores = [f"PSNR render vs target {psnr(imgs['render'], imgs['target']):.2f} dB"]
    if "truth" in imgs:
        scores.append(f"render vs truth {psnr(imgs['render'], imgs['truth']):.2f} dB")
        scores.append(f"target vs truth {psnr(imgs['target'], imgs['truth']):.2f} dB")
    if "supervised_fraction" in imgs:
        scores.append(f"restored on {100 * imgs['supervised_fraction']:.1f} % of the frame")
    imgui.text_wrapped(";  ".join(scores))
    if "supervised" in imgs:
        tip("Magenta: where the pseudo-target pulls the model towards the restorer: holes of the render, and "
            "surfaces no train camera sees from near this view where the restorer is confident. Elsewhere the "
            "target is the render itself (stage2.pseudo_target=gated) and the real frames constrain the model; "
            "--paper-stage2 restores every pixel", viewer)
    avail = imgui.get_content_region_avail()
    h, w = imgs["render"].shape[:2]
    mode = MODES[ui["mode"]]
    if mode == "side by side":
        panes = [(k, lab) for k, lab in labels if k in imgs]
        cols, scale = grid_layout(len(panes), w, h, avail.x, avail.y, imgui.get_text_line_height_with_spacing())
        for i, (k, lab) in enumerate(panes):
            if i % cols:
                imgui.same_line()
            imgui.begin_group()
            shown_label = elide(lab, w * scale)
            imgui.text(shown_label)
            if shown_label != lab:
                tip(lab, viewer)
            tex = viewer.image_texture(f"compare_{k}", imgs[k])
            imgui.image(imgui.ImTextureRef(tex.glo), imgui.ImVec2(w * scale, h * scale))
            imgui.end_group()
    else:
        if mode == "split":
            leave_room_for_label("split", at_most=200)
            _, ui["split"] = imgui.slider_float("split", ui["split"], 0.0, 1.0)
            tip("where the line between render (left) and pseudo-target (right) is, as a share of the width", viewer)
            cut = int(round(ui["split"] * w))
            img = np.concatenate([imgs["render"][:, :cut], imgs["target"][:, cut:]], 1)
            if 0 < cut < w:
                img[:, cut] = (1.0, 1.0, 0.0)
            caption = "left: render | right: pseudo-target"
        else:
            b_key = not imgui.get_io().want_text_input and imgui.is_key_pressed(imgui.Key.b, False)  # not while typing
            switch = imgui.button("A/B (B key)")
            tip("switch between the render (A) and the pseudo-target (B)", viewer)
            if switch or b_key:
                ui["show_b"] = not ui["show_b"]
            img = imgs["target"] if ui["show_b"] else imgs["render"]
            caption = "B: pseudo-target (cache)" if ui["show_b"] else "A: render (current model)"
        same_line_if_fits(imgui.calc_text_size(caption).x)
        imgui.text(caption)
        scale = min(avail.x / w, max(avail.y - 24, 32) / h)
        tex = viewer.image_texture("compare_main", img)
        imgui.image(imgui.ImTextureRef(tex.glo), imgui.ImVec2(w * scale, h * scale))


def grid_layout(n: int, w: float, h: float, avail_w: float, avail_h: float, label_h: float) -> tuple[int, float]:
    """(columns, image scale) that show ``n`` w x h images, each under a label line, as large
    as the area allows (one row in a wide panel, a grid in a tall one)."""
    best = (n, 0.0)
    for cols in range(1, n + 1):
        rows = -(-n // cols)
        gap = 8.0
        scale = min((avail_w - gap * cols) / (w * cols), (avail_h - rows * (label_h + gap)) / (h * rows))
        if scale > best[1]:
            best = (cols, scale)
    return best[0], max(best[1], 0.05)
