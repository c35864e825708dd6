"""Simulated grain photos: COCO labels that match the rendered seeds, seeded and split-aware."""

from __future__ import annotations

import json

import numpy as np
import pytest

from seedmap.detect.labels import CocoSource, segmentation_mask
from seedmap.sim.photos import PhotoSimConfig, simulate_photos
from seedmap.sim.photos.compose import LIGHTS, render_photo
from seedmap.sim.photos.objects import VARIETIES
from seedmap.sim.photos.textures import BACKGROUNDS
from tests.helpers.cli import run_cli

SMALL = {"long_side": (240, 320), "seed_px": (6.0, 12.0)}


@pytest.fixture(scope="module")
def photos(tmp_path_factory):
    out = tmp_path_factory.mktemp("photos") / "p"
    cfg = PhotoSimConfig(count=4, seed=3, **SMALL)
    simulate_photos(cfg, out, progress=False)
    return out, cfg


def test_labels_are_the_visible_seeds(photos):
    out, cfg = photos
    coco = json.loads((out / "labels.json").read_text())
    assert len(coco["images"]) == 4 and coco["categories"] == [{"id": 1, "name": "seed"}]
    seqs = np.random.SeedSequence(cfg.seed).spawn(cfg.count)
    n_seeds = 0
    for i, im in enumerate(coco["images"]):
        ph = render_photo(np.random.default_rng(seqs[i]), cfg.split, cfg.long_side, cfg.seed_px, cfg.empty_fraction)
        anns = [a for a in coco["annotations"] if a["image_id"] == im["id"]]
        assert len(anns) == len(ph.seeds)
        h, w = ph.ids.shape
        assert (im["width"], im["height"]) == (w, h)
        sizes = []
        for a, k in zip(anns, ph.seeds):
            m = segmentation_mask(a["segmentation"], h, w).astype(bool)
            assert np.array_equal(m, ph.ids == k)
            ys, xs = np.nonzero(m)
            x, y, bw, bh = a["bbox"]
            assert (x, y, x + bw, y + bh) == (xs.min(), ys.min(), xs.max() + 1, ys.max() + 1)
            assert a["area"] == m.sum()
            sizes.append(np.sqrt(bw * bh))
        n_seeds += len(anns)
        if anns:
            assert im["seed_px"] == pytest.approx(np.median(sizes), abs=1e-3)
            # the drawn seed diameter is what the labels measure (within the spread of seed sizes and occlusion)
            assert im["seed_px"] == pytest.approx(im["conditions"]["seed_diameter_px"], rel=0.3)
    assert n_seeds > 20


def test_readable_as_user_labels(photos):
    out, _ = photos
    src = CocoSource(out / "labels.json")
    li = src[0]
    assert li.image.ndim == 3 and li.labels.shape == li.image.shape[:2]


def test_seeded_and_independent_of_count(photos, tmp_path):
    out, cfg = photos
    again = tmp_path / "again"
    simulate_photos(cfg.model_copy(update={"count": 2}), again, progress=False)
    for name in ("00000", "00001"):
        a = sorted(out.glob(name + ".*"))[0]
        assert a.read_bytes() == (again / a.name).read_bytes()


@pytest.mark.parametrize("split", ["heldout", "validation"])
def test_unseen_splits_draw_only_their_own_surfaces(split):
    """validation and heldout: backgrounds, lights and varieties of their own, disjoint from training and from each
    other (the panicle scenes are shared); training photos never draw an unseen condition."""
    own = {k for k, (s, _) in BACKGROUNDS.items() if s == split}
    train = {k for k, (s, _) in BACKGROUNDS.items() if s == "train"}
    other = {k for k, (s, _) in BACKGROUNDS.items() if s not in (split, "train")}
    assert own and train and other and not own & train and not own & other
    assert {"sieve", "tablecloth", "burlap", "gravel"} <= set(BACKGROUNDS) - train
    assert {"pebbles", "mottled", "cloth"} <= train
    own_vars = {k for k, v in VARIETIES.items() if v[0] == split}
    own_lights = {k for k, s in LIGHTS.items() if s == split}
    assert own_vars and own_lights
    seen, lights, vars_ = set(), set(), set()
    for s in range(24):
        c = render_photo(np.random.default_rng(s), split, (160, 200), (5.0, 8.0), 0.0).conditions
        seen.add(c["background"])
        lights.add(c["light"])
        vars_ |= set(c["varieties"])
        assert c["background"] in own | {"canopy", "night", "sky"}
        assert LIGHTS[c["light"]] in ("train", split)
        assert all(VARIETIES[v][0] in ("train", split) for v in c["varieties"])
    assert seen & own and lights & own_lights and vars_ & own_vars
    for s in range(12):
        ph = render_photo(np.random.default_rng(s), "train", (160, 200), (5.0, 8.0), 0.0)
        assert ph.conditions["background"] in train
        assert LIGHTS[ph.conditions["light"]] == "train"
        assert all(VARIETIES[v][0] == "train" for v in ph.conditions["varieties"])


def test_one_setup_shares_its_conditions(tmp_path):
    """setup=true: every photo has the setup's background, light and varieties, seeds within 10 % of one size;
    the setup follows the seed, and photo i still depends only on (seed, i)."""
    cfg = PhotoSimConfig(count=4, seed=11, split="heldout", setup=True, empty_fraction=0.0, **SMALL)
    a = simulate_photos(cfg, tmp_path / "a", progress=False)
    coco = json.loads((a / "labels.json").read_text())
    conds = [im["conditions"] for im in coco["images"]]
    setup = coco["info"]["setup"]
    for c in conds:
        assert (c["background"], c["light"], c["varieties"]) == (setup["bg"], setup["light"], setup["varieties"])
    d = np.array([c["seed_diameter_px"] for c in conds])
    assert d.max() / d.min() <= 1.1 ** 2 + 1e-6 and d.max() > d.min()
    b = simulate_photos(cfg.model_copy(update={"count": 2}), tmp_path / "b", progress=False)
    assert (a / "00001.jpg").read_bytes() == (b / "00001.jpg").read_bytes()
    others = {json.loads((simulate_photos(cfg.model_copy(update={"seed": s, "count": 1}), tmp_path / str(s),
                                                progress=False) / "labels.json").read_text())["info"]["setup"]["bg"]
              for s in range(12, 18)}
    assert len(others) > 1  # another seed, another setup


def test_cli_refuses_existing_folder_and_bad_config(photos, tmp_path, monkeypatch, capsys):
    out, _ = photos
    assert run_cli(["simulate", "photos", "--out", out, "-n", "1", "-q"], monkeypatch) == 2
    assert "exists" in capsys.readouterr().err
    bad = tmp_path / "bad"
    assert run_cli(["simulate", "photos", "--out", bad, "--split", "fog", "-q"], monkeypatch) == 2
    assert run_cli(["simulate", "photos", "--out", bad, "--set", "seed_px=[2,4]", "-q"], monkeypatch) == 2
    assert not bad.exists()


def test_training_photos_vary_white_balance_and_exposure_held_out_ones_do_not():
    """Training photos: some under-exposed (``dim``); held-out photos and one-setup photos never."""
    dims = [render_photo(np.random.default_rng(s), "train", (160, 200), (5.0, 8.0), 0.0).conditions["dim"]
            for s in range(24)]
    assert 0 < sum(dims) < 24
    assert not any(render_photo(np.random.default_rng(s), "heldout", (160, 200), (5.0, 8.0), 0.0).conditions["dim"]
                   for s in range(8))


def test_random_patterns_repeat_at_the_seed_scale():
    """The training ``pattern`` background: a geometric motif whose repeat (the longest period with at least a
    quarter of the strongest one's power, shorter strong ones being its harmonics; the folds' shading left
    out) lies within 0.4-8 seed diameters
    (checks repeat over two periods), in varied colours."""
    seed_px = 10.0
    periods, colours = [], []
    for s in range(10):
        img = BACKGROUNDS["pattern"][1](np.random.default_rng(s), 256, 256, seed_px)
        g = img.mean(axis=2)
        p = np.abs(np.fft.rfft2(g - g.mean())) ** 2
        fyy = np.fft.fftfreq(256)[:, None] * 256
        p[np.hypot(fyy, np.arange(p.shape[1])[None, :]) < 2.5] = 0.0  # the folds' shading, not the motif
        ky, kx = np.nonzero(p >= 0.25 * p.max())
        fy = np.where(ky <= 128, ky, ky - 256)
        periods.append(256 / np.hypot(fy, kx).min())
        colours.append(img.reshape(-1, 3).mean(axis=0))
    periods = np.array(periods)
    assert np.all((periods >= 0.4 * seed_px * 0.9) & (periods <= 8 * seed_px * 1.1)), periods
    assert np.ptp(np.array(colours), axis=0).max() > 0.2
