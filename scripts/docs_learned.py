"""The results page of the paper's detector at reduced width (``learned.json``) and its README row."""

from __future__ import annotations

from docs_format import fixed, load, num, source, table


def _row(name: str, r: dict, learned: bool) -> list[str]:
    return [f"`{name}`", fixed(r["precision"]), fixed(r["recall"]), f"**{fixed(r['f1'])}**", num(r["kp_median_px"]),
            num(r["kp_p90_px"]), num(r["cpu_ms_median"]), num(r["wall_ms_median"]),
            fixed(r.get("mask_iou_mean")) if learned else "–"]


def page_learned(cmds: dict[str, str]) -> tuple[str, str] | None:
    d = load("learned.json")
    if d is None:
        return None
    det = d["detector"]
    head = ["detector", "precision", "recall", "F1", "keypoint error median (px)", "p90 (px)", "CPU ms / image",
            "wall ms / image", "mask IoU (pix2pix vs GT)"]
    pooled = d["pooled"]
    body = [source("learned.json", cmds),
            f"Commit `{d.get('commit', '?')}`, {d.get('date', '?')}, {d.get('machine', '?')}.\n",
            f"`{det}` (the paper's Faster R-CNN + pix2pix at reduced width, shipped ONNX weights) beside `fast` on "
            "held-out simulated ranges, scored alike: a detection is correct at box IoU ≥ 0.5 (one-to-one), "
            "ground-truth slivers below the detectable size are ignored, the keypoint error is the ellipse centre's "
            "distance to the true seed centre. One thread each, the same images in the same run. The mask IoU "
            "compares each matched detection's pix2pix mask with its seed's ground-truth mask in the same box crop. "
            f"`{det}`'s score threshold ({d['threshold']}) was chosen on `{d['val']}` (best F1), not on these "
            "ranges. This is a reduced model: its numbers are not the paper's.\n",
            "## Pooled\n", table(head, [_row("fast", pooled["fast"], False), _row(det, pooled[det], True)]),
            f"\n`{det}` costs {num(pooled['cpu_ratio'])}× `fast`'s CPU per image.\n", "## Per range\n"]
    rows = []
    for name, r in d["datasets"].items():
        rows.append([f"`{name}`"] + _row("fast", r["fast"], False)[1:4] + _row(det, r[det], True)[1:4]
                    + [fixed(r[det].get("mask_iou_mean"))])
    body.append(table(["dataset", "fast P", "fast R", "fast F1", f"{det} P", f"{det} R", f"{det} F1", "mask IoU"],
                      rows))
    sw = d.get("val_sweep") or {}
    if sw:
        body.append(f"\nThreshold sweep on `{d['val']}` (`{det}`):\n")
        body.append(table(["threshold", "precision", "recall", "F1"],
                          [[t, fixed(v["precision"]), fixed(v["recall"]), fixed(v["f1"])] for t, v in sw.items()]))
    return "The paper's detector, reduced (frcnn-pix2pix-lite)", "\n".join(body)


def glance_learned() -> list[str] | None:
    """The README row of ``learned.json``."""
    d = load("learned.json")
    if d is None:
        return None
    det, p = d["detector"], d["pooled"]
    return [f"seed detection, `{det}` (the paper's pipeline at reduced width), {len(d['datasets'])} held-out ranges",
            f"F1 {fixed(p[det]['f1'])} pooled (`fast` {fixed(p['fast']['f1'])} on the same images); mask IoU "
            f"{fixed(p[det].get('mask_iou_mean'))}; {num(p[det]['cpu_ms_median'])} ms CPU per image "
            f"({num(p['cpu_ratio'])}× `fast`)", "[learned](docs/results/learned.md)"]


__all__ = ["glance_learned", "page_learned"]
