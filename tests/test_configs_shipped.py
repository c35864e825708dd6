"""The config presets shipped in configs/ load and select what their comments say."""

from __future__ import annotations

from pathlib import Path

from seedmap.config import load_config
from seedmap.slam.config import SlamConfig

CONFIGS = Path(__file__).resolve().parents[1] / "configs"


def test_learned_association_preset():
    cfg = load_config(SlamConfig, CONFIGS / "learned_association.yaml", [])
    a = cfg.association
    assert (a.stereo_prior, a.prior_score, a.temporal_score, a.stereo_history) == ("sgbm", "mlp", "mlp", True)
    assert cfg.gates.stereo_border_px == 0 and cfg.gates.temporal_border_px == 0
    default = SlamConfig()
    assert default.association.stereo_history is False and default.gates.stereo_border_px > 0
    # --set still overrides a preset
    cfg = load_config(SlamConfig, CONFIGS / "learned_association.yaml", ["gates.stereo_border_px=200"])
    assert cfg.gates.stereo_border_px == 200
