"""Semantic seed association: the paper's neighbour-structure cost + gated linear assignment.

Why: seeds carry no distinctive appearance, but panicles are rigid, so the *geometry* of a seed's
neighbourhood (distances to its left / right / top / bottom neighbours) is nearly the same in the
two images of a stereo pair and in two consecutive frames. The paper turns this into a cost and
solves a linear sum assignment (Hungarian) problem.

Cost (paper + facts.md, full-resolution pixels). For keypoint ``p`` in its own image the neighbour
sets are ``L = {q : 0 < x_p - x_q < Δ, |y_q - y_p| < ε}`` and likewise ``R, T, B`` (``T``/``B`` swap
the roles of x and y). ``S_d(p)`` is the sum of Euclidean distances from ``p`` to the set ``d``.
The cost of pairing ``a`` (image A) with ``b`` (image B) is::

    C(a, b) = |y_a - y_b| + r * sum_d ratio_d,
    ratio_d = max(S_d(a), S_d(b)) / (min(S_d(a), S_d(b)) + 0.01)   if both sets are non-empty
            = impossible_cost                                      if exactly one is empty
            = 0                                                    if both are empty

(the symmetric ratio of the original code; the paper's plain ratio is minimised by a large
denominator, see facts.md). ``Δ = 1000``, ``ε = 15``, ``r = 10``, keep a pair when ``C ≤ 200``.

Resolution: every parameter of the paper is in pixels of a 4096 px wide image. Rather than
scaling each parameter separately we express keypoints in *full-resolution-equivalent pixels*
(multiply by ``4096 / width``) before computing the cost, so Δ, ε, the 0.01 regulariser, the
|Δy| term and therefore the acceptance threshold 200 all keep the paper's meaning at any
resolution (the ratio terms are scale-free anyway; only |Δy| and the 0.01 are not). The gates use
:class:`~seedmap.associate.base.GateConfig` scaled to the image width, exactly as the descriptor
baselines do, so every matcher sees the same geometric constraints.

Cases the paper leaves open (our choices):

* Zero keypoints in either image -> no matches (empty :class:`Matches`), never an error.
* Rectangular problems (N != M) -> ``scipy.optimize.linear_sum_assignment`` handles them: every
  keypoint of the smaller side is assigned, pairs through a gated entry are removed afterwards.
* Many more keypoints in one image than the other -> only keypoints with at least one feasible
  (gated-in) partner enter the assignment, which keeps the problem small and avoids forcing
  assignments through infeasible entries.
* A direction where only one side has neighbours -> ``impossible_cost`` (a large finite cost,
  above the acceptance threshold, so such a pair is never kept but the solver stays finite).
* Gated-out pairs -> ``GATED`` (1e9) in the cost matrix, removed after the assignment.
* Neighbour sets are built from *all* keypoints of the image (also those the gates or border
  margins exclude from matching), because they describe the visible structure.

Acceptance threshold: the ratio terms are scale-free, and with keypoints in full-resolution
units the |Δy| term is too, so the paper's 200 is kept unchanged at every resolution (at equality
of all four neighbour sums a pair costs ~4 r = 40 plus its |Δy|).

Known weakness and our options. The ratio of *raw sums* changes when a neighbour is visible in
only one image (image border, occlusion, detector miss), and in dense panicles (2,000-8,000
keypoints per image, ~3 px apart on the simulated ranges) many neighbouring seeds have nearly
the same sums, so one assignment on this cost alone is ambiguous (measured with the ``gt``
oracle: stereo precision ~0.3, temporal ~0.57). Options (the paper's method stays the default of
:class:`SemanticConfig`):

* ``refine="consensus"`` (:func:`consensus_assign`, session 1): mutual best pairs of the paper's
  cost give a local median displacement that gates a second assignment.
* ``refine="field"`` (:func:`field_assign`, the SLAM default): the paper's cost is assigned inside
  a *displacement-field prior*. Panicles are rigid and smooth, so the disparity (stereo) or the
  frame-to-frame shift (temporal) of a seed is close to its image neighbours'. Steps:

  1. coarse field (:func:`coarse_field`): every candidate pair inside the search box (stereo:
     disparity between the minimum-disparity gate and ``field_max_disparity_px``, rows within
     ``field_stereo_band_px``; temporal: ``prediction_tol_px`` around the constant-velocity
     prediction, or the whole travel gate on the first pair) votes in a displacement histogram
     of its image cell (``field_cell_px``); the peak of the histogram smoothed over 3 x 3 cells is
     the cell's displacement (true pairs agree, wrong ones spread out);
  2. ``field_iters`` refinements: candidates within ``field_gate_sigma`` normalised residuals of
     the field (window shrinking geometrically from ``field_coarse_tol_px`` to the expected
     spread ``field_*_sigma_px``), their *mutual best* pairs by residual that pass a ratio test
     (``field_seed_ratio``) are the unambiguous "seed" matches; the field at a seed match is the
     median displacement of its ``field_k`` nearest other seed matches and every keypoint takes
     the field of its nearest seed match (:func:`local_field`); for rectified stereo the v
     displacement is fixed to 0 (epipolar rows);
  3. final assignment of ``paper cost + field_weight * residual^2`` (residual in units of the
     expected spread) with :func:`assign_capped`: unlike the paper's gated Hungarian, which
     first maximises the number of pairs and so forces keypoints without a visible partner onto
     a neighbour's partner, a keypoint may stay unmatched (pair kept only when its cost is below
     ``max_cost + field_weight * field_gate_sigma^2``);
  4. ambiguity test: a kept pair's residual must be below ``field_ratio`` x the residual of every
     competitor candidate sharing one of its keypoints.

  All steps are vectorised (KD-tree box queries, bincount histograms, one sparse min-weight
  matching); no Python loop over keypoints, pairs or components.
  Measured limits (``seedmap eval associate``, gt oracle, 1434 px): even with the *true* local
  field, a seed's own disparity deviates from its neighbours' by 2.4 px (90th percentile; seeds
  of a loose panicle lie at different depths) and its ellipse centre moves by partial occlusion,
  while neighbours are ~3 px apart, so geometry alone bounds stereo precision at ~0.8-0.9 and
  temporal at ~0.95-0.98 on these ranges; the paper's neighbour-sum term adds next to nothing
  among the candidates that survive the field gate (``field_weight`` makes the residual the
  dominant term). RANSAC on the 3D matches removes the remaining wrong pairs.
* ``temporal_prediction=True`` gates temporal pairs around a constant-velocity prediction of the
  image shift (the median shift of the previous frame pair; u for ``consensus``, u and v for
  ``field``).
* ``neighbours="overlap"`` counts, for temporal matching, only neighbours inside the field of view
  common to both frames given the predicted shift.

* ``stereo_carry=True`` (with ``refine="field"``): the *stereo-temporal loop* (:func:`loop_associate`,
  run by :class:`SeedMatcher` frame after frame). Why: per-frame stereo is ambiguous at this seed
  density (a seed's disparity differs from its neighbours' by ~2.4 px, they are ~3 px apart), while
  the frame-to-frame motion is small and shared by all seeds. For frame t given t-1:

  1. temporal matching left(t-1)->left(t) *and* right(t-1)->right(t) with the ``field`` machinery,
     independently of each other (the right one starts from the left one's smooth field, and the
     left one from the previous frame's flow, so no coarse histogram is needed after frame 1);
  2. *carry*: a stereo pair (a', b') of t-1 becomes (T_L(a'), T_R(b')) when that pair passes the
     stereo gates and the *loop residual*: its change of (disparity, row offset) since t-1, minus
     the leave-one-out median change of its ``carry_k`` carried neighbours, within
     ``carry_tol_px`` (a wrong temporal match on one side moves one end by a seed spacing); when
     only one side was matched in time the other end is predicted from it and taken if a unique
     untaken keypoint lies within the same tolerance (``carry_recover``); conflicts cannot arise
     (the three matchings are one-to-one);
  3. *new* stereo: the ``field`` stereo of the keypoints not carried (fewer points and fewer
     distractors), starting from the disparity field of the carried pairs;
  4. *parallax test*: along a left track of k frames the u shift of a static seed is
     ``alpha_k * disparity + beta`` (translation along the rows, smooth rotation terms), so a wrong
     stereo partner a few px off in u leaves a residual ``alpha_k * delta`` that grows with k, while
     the noise does not; the residual minus its local leave-one-out median must stay within
     ``parallax_tol_px``. A wrong pair carried *consistently* (same wrong partner in both frames)
     passes the loop residual but not this test. Pairs failing it are dropped for good;
     pairs without a track yet (new in view) are kept by the matcher as candidates and carried,
     and with ``stereo_output="verified"`` output only once tested;
  5. loop check of the left temporal matches: a pair (a, b) is dropped when the stereo partner of
     a, moved by T_R, is not the stereo partner of b, when the carried pair through it failed the
     loop residual, or when its shift disagrees with the disparity of a at t-1 (same model as 4,
     ``temporal_parallax_tol_px``).

  Frame 0 (no history) is the per-frame ``field`` stereo; a frame index that does not follow the
  previous one starts a new sequence. No ground truth is used. Measured (``seedmap eval
  associate``, gt oracle, 1 m seed-3 range): stereo precision 0.84 -> 0.92 at a higher recall,
  temporal unchanged overall (0.97; among the temporal pairs with stereo at both ends - the ones
  the SLAM front-end uses - 0.996); the targets P >= 0.99 / R >= 0.90 are still not met. It is
  *not* the SLAM default: with it the SLAM trajectory of that range gets worse (ATE 11.6 vs
  5.4 mm: a pitch / vertical-translation drift over the first ten frames although the front-end
  finds 1.5x more RANSAC-verified 3D matches). The carried *stereo* is the cause: the loop's
  temporal matches with the per-frame stereo give 5.1 mm (``stereo_output="frame"``, the loop then
  only checks time). Suspect, not proven: the per-frame field rejects seeds whose disparity
  disagrees with their neighbours' (partly occluded, centre biased in one image), the loop keeps
  such a pair as long as the bias is consistent over time, and the back-end treats its
  time-correlated errors as independent.

* ``stereo_prior="sgbm"`` (session 4; needs the images, i.e. :meth:`SeedMatcher.features`): the
  stereo prior is the dense disparity of OpenCV's StereoSGBM (:mod:`seedmap.associate.disparity`)
  at each left keypoint instead of the smooth keypoint field: candidates around ``(u - D, v)``
  within ``field_gate_sigma`` x ``prior_sigma_px``, the paper's cost + ``field_weight`` x residual^2
  assigned with :func:`assign_capped`, ambiguity test ``prior_ratio`` (:func:`prior_assign`). SGBM
  searches only the disparities of the previous frame's matches +- ``sgbm_margin_px`` (the first
  frame of a sequence: of a ``refine`` matching), so ~64-96 disparities at 1434 px.
  ``sgbm_lr_tol_px`` adds a left-right check with the right image's SGBM disparity (a second run),
  ``prior_max_dev_px`` drops pairs whose disparity disagrees with their neighbours'. Why: a seed
  in front of or behind its panicle has a disparity the smooth field cannot predict, SGBM sees it.
  Measured (gt oracle, today's detectable-seed oracle): stereo precision and recall both above the
  field's; not the SLAM default because the SLAM trajectory drifts more with it (see
  ``SlamAssociationConfig``). With the stereo-temporal loop it only serves the first frame.

* ``prior_score="learned"`` (session 6, with ``stereo_prior="sgbm"``; :func:`scored_prior_assign`):
  the candidates around ``(u - D, v)`` are scored by a logistic model of five cues instead of the
  residual alone: u and v residual from the SGBM prior, the NCC of 11 x 11 px grey patches around
  the two keypoints (:func:`seedmap.associate.disparity.patch_descriptors`), the candidate's
  disagreement with the prior smoothed over its ``field_k`` nearest keypoints, and the paper's
  neighbour-ratio cost; weights ``score_weights`` fitted on the gt-oracle candidates of the tuning
  ranges (seeds 3 and 11). Assignment on ``-log-odds`` with a minimum log-odds and a log-odds margin
  over every competitor (ambiguity test). Why: the session-5/6 breakdown of the sgbm path (slam_r1,
  gt oracle, 40,936 gated true pairs) lost 5.6 % outside the prior's gate (SGBM off by > 2.45 px at
  a depth edge) and 6.8 % to the residual ratio test, and 2 % of its output was wrong (43 % of those
  because the partner is a sliver the oracle does not emit); the extra cues resolve most of the
  ratio-test ties and the wider window (``score_gate_sigma``) recovers part of the gate losses.
  Measured (``seedmap eval associate``, gt oracle, stereo P / R over gated pairs): seed 3 0.979 /
  0.875 -> 0.991 / 0.927, seed 11 0.969 / 0.880 -> 0.984 / 0.889; fresh ranges rendered after the
  freeze: seed 13 0.981 / 0.900 -> 0.991 / 0.942, seed 14 0.969 / 0.852 -> 0.986 / 0.884; ~+15 ms
  CPU per frame over the sgbm prior (patches + scoring). Not the SLAM default: ATE better on the 5 m
  ranges (paper2 gt 14.4 -> 11.3 mm, paper3 gt 11.4 -> 10.6 mm, fast 10.2 -> 9.7 mm) but the 1 m
  range with the fast detector gets worse (4.7 -> 5.6 mm) and the first-pose-aligned error grows on
  four of six runs.
* ``temporal_min_ncc`` (session 6): temporal pairs whose patch NCC is below the threshold are
  dropped (same camera, ~1 cm apart: a true pair's patches are nearly the same, 95 % above 0.58).
  At 0.3: temporal precision seed 11 0.984 -> 0.990 (R gated 0.918 -> 0.906), seed 3 0.9995 ->
  0.9996 (0.959 -> 0.942). Not the SLAM default: paper2 gt ATE 14.4 -> 17.0 mm with it.

* ``prior_score="mlp"`` (session 7, with ``stereo_prior="sgbm"``; :func:`mlp_prior_assign`): the
  candidates within ``mlp_gate_sigma`` (10) of ``(u - D, v)`` are scored by a network with two
  small ReLU hidden layers (32, 16) over the 17 cues of :func:`cue_features` - the five above plus
  grey NCC at 7 and 19 px, colour NCC, chromaticity and brightness differences, the dense
  disparity's range at the left keypoint (depth edge), an occlusion margin (a nearer surface of
  the left disparity map covering the keypoint's right-image position), ellipse sizes and their
  ratio, and the candidates' crowding -, assigned as the learned score (:func:`assign_logits`,
  ``mlp_min_logit`` 1.0, ``mlp_margin`` 1.0). Weights: ``weights/stereo_score_s7.json``, fitted by
  ``benchmarks/fit_assoc_score.py`` on the gt-oracle candidates of seeds 3, 11, 16, 17, 18 and 19
  (never 13-15). Why: the learned score's wrong pairs on seed 11 are mostly cross-occlusions (a
  seed seen only in the left view paired with a neighbour at nearly the same depth, where SGBM
  gave the left seed its occluder's disparity, 5.9 px too large, median); no single cue separates
  them (the occlusion margin alone drops 3 % of the true pairs for 11 % of the wrong ones), the
  network over all of them does. The threshold 1.0 is the one of {0, 0.5, 1, 1.5, 2} at which
  every leave-one-range-out fit range kept P >= 0.99 and gated R >= 0.90.
  Measured once after the freeze (``seedmap eval associate``, gt oracle, with
  ``temporal_min_ncc=0.3``; stereo P / R gated, learned -> mlp): seed 13 0.991 / 0.942 -> 0.997 /
  0.948, seed 14 0.986 / 0.884 -> 0.993 / 0.902, seed 15 (rendered after the freeze) 0.984 / 0.879
  -> 0.993 / 0.898 (fit ranges: seed 3 0.9905 / 0.927 -> 0.996 / 0.939, seed 11 0.984 / 0.889 ->
  0.993 / 0.907); ~+90-140 ms CPU per frame over the learned score (cues of both images ~60 ms,
  wider window and network ~40 ms). Not the SLAM default: on the 1 m range (slam_r1) the
  trajectory is not better than the default's (gt ATE 4.7 -> 5.1 mm, first-pose-aligned 12.7 ->
  19.4 mm; fast 4.7 -> 5.0 mm, 21.4 -> 23.9 mm; all 100 % GT-validated). On drawn-blob synthetic
  images (benchmarks/bench_slam.py) it is less precise than the learned score: the network knows
  rendered seeds only.

* ``temporal_score="mlp"`` (session 8, with ``refine="field"``; :func:`mlp_temporal_assign`,
  :meth:`SeedMatcher.temporal_candidates`): the temporal pairs are chosen by a network of the same
  shape as the stereo one over the 19 cues of :func:`temporal_cue_candidates` instead of the
  ``field`` path's cost, cap and ratio test. Candidates lie within ``temporal_mlp_gate_sigma`` (8)
  of the field path's local shift field (:func:`field_estimate`); cues: u / v residuals from it,
  a *parallax* residual (a static seed's shift is ``alpha * disparity + beta``, so a seed nearer
  than its neighbours leaves the smooth field by ``alpha`` times its disparity deviation), the
  change of disparity between the frames (the camera travels along the rows: a seed's depth stays),
  the disparity deviation from the neighbours, the paper's neighbour cost and the appearance cues
  of the stereo network between the two left images (grey NCC at 7 / 11 / 19 px, colour NCC,
  chromaticity, brightness, ellipse sizes, crowding). Disparities are the dense SGBM disparity when
  ``stereo_prior="sgbm"`` ran, else the disparity of the keypoint's stereo match. Weights
  ``weights/temporal_score_s8.json`` fitted by ``benchmarks/fit_assoc_temporal.py`` on the
  gt-oracle candidates of seeds 3, 11 and 16-21 (never 13-15, 25, 26); ``temporal_mlp_min_logit``
  1.0 keeps P >= 0.99 and gated R >= 0.96 on every leave-one-range-out fold (grid -1 .. 2). Why
  (session-8 anatomy of the ``field`` path, gated true temporal pairs, fit ranges): 0.3-6 % fall
  outside the 3.5-sigma field window (a seed at another depth than its neighbours, or its centre
  moved by occlusion), another 1.5-3 % over the cost cap (the paper's neighbour ratio is
  ``impossible_cost`` when a neighbour set is empty in one frame only), 0.1-0.2 % in the assignment
  and ratio test, 0.4-2 % to the NCC check; the network's window holds 98.7-100 % of them.
  Measured once after the freeze (``seedmap eval associate``, gt oracle, with the sgbm prior and the
  mlp stereo score; temporal P / R gated, field + ``temporal_min_ncc=0.3`` -> mlp): seed 13 0.997 /
  0.936 -> 0.9986 / 0.983, 14 0.997 / 0.931 -> 0.998 / 0.980, 15 0.991 / 0.886 -> 0.996 / 0.966,
  fresh 25 0.995 / 0.904 -> 0.997 / 0.966, fresh 26 0.996 / 0.915 -> 0.998 / 0.977; temporal CPU
  ~+30 ms per frame (the left-image cues are shared with the mlp stereo score).
  Session 8 also refitted the stereo network on eight ranges (seeds 3, 11, 16-21; same cues and
  shape; ``benchmarks/fit_assoc_score.py ... --report benchmarks/results/fit_assoc_score_s8.json``;
  leave-one-range-out at ``mlp_min_logit`` 1.0: P >= 0.991, gated R >= 0.909 on every fold, on the
  six folds shared with the session-7 fit gated R 0.923 vs 0.921 on average). On the five held-out
  ranges it kept P but lost 0.1-0.3 pp gated R against the session-7 weights (seed 15 0.898 ->
  0.895, 25 0.880 -> 0.878), so ``stereo_score_s7.json`` stays and the refit was not shipped.

* ``stereo_history=True`` (session 9, with ``stereo_prior="sgbm"``, ``prior_score="mlp"`` and
  ``temporal_score="mlp"``; :func:`history_prior_assign`, :meth:`SeedMatcher._history`): the stereo
  candidates of frame t are also scored with the seed's stereo pair at t-1. Order: the temporal
  network needs only the dense disparity (not the stereo matches), so :meth:`SeedMatcher.features`
  runs the temporal matching t-1 -> t *before* the stereo matching of t and keeps it for the
  ``match_temporal`` call that follows (same network, same inputs); each left keypoint tracked to a
  stereo pair of t-1 gets a predicted disparity and row offset (:func:`history_prior`: the t-1 pair's
  plus the local median change of the tracked seeds' dense disparity), a second candidate window
  of ``history_gate_sigma`` around that position (a seed whose SGBM disparity is the occluder's keeps
  its disparity of t-1), and six cues (:data:`HISTORY_CUE_NAMES`: whether it has a history, the
  disparity and row residuals from it, the NCC of the candidate's right patch with the t-1
  partner's right patch at two sizes - the "loop-closed" check -, and how much the dense prior
  disagrees with the history). One network of the ``mlp`` shape over the 17 + 6 cues
  (``weights/stereo_history_s9.json``, ``kind="stereo_history"``) scores all candidates, also those
  without a history (the first frame, seeds entering the view). Why (session-9 anatomy of the
  ``mlp`` path on the fit ranges 3, 11, 16-21, gated true pairs): 5.4-9.4 % are lost, 1.6-3.8 %
  outside the 10-sigma window, 3.6-6.3 % below the log-odds threshold, < 0.3 % to the margin or the
  assignment; 1.6-3.0 % of the gated true pairs are lost although their left keypoint is tracked to
  the right stereo pair of t-1 (the history points at the true partner for 96-100 % of those).
  Fitted by ``benchmarks/fit_assoc_history.py`` on seeds 3, 11, 16-21 (never 13-15, 25-28);
  ``history_min_logit`` 0.5 / ``history_margin`` 1.5 are the setting of a 5 x 3 grid with the best
  worst-fold gated recall among those where every leave-one-range-out fold kept P >= 0.993 (worst
  fold P 0.9930, gated R 0.930; the 17 cues alone on the same candidates: 0.893 at P >= 0.993).
  Measured once after the freeze (``seedmap eval associate DATA --detector gt``, sgbm + both
  networks, without -> with the option; stereo P / gated R): seed 13 0.9966 / 0.948 -> 0.9972 /
  0.972, 14 0.9933 / 0.902 -> 0.9949 / 0.942, 15 0.9928 / 0.898 -> 0.9942 / 0.937, 25 0.9927 / 0.880
  -> 0.9945 / 0.930, 26 0.9939 / 0.928 -> 0.9947 / 0.956, fresh 27 0.9961 / 0.935 -> 0.9971 / 0.965,
  fresh 28 0.9930 / 0.876 -> 0.9943 / 0.924; temporal P / gated R unchanged in four decimals (at
  most 4 of ~50,000-76,000 correct temporal pairs differ per range: the SGBM search range follows
  the previous frame's stereo matches, so the dense disparity differs slightly); association CPU per frame
  about the same (the temporal work moves into the stereo step, +~30 ms for the extra candidates).
  Not the SLAM default (``seedmap slam DATA --detector gt|fast``, SE(3)- / first-pose-aligned ATE mm,
  all 100 % GT-validated; default -> sgbm + both networks -> + stereo_history): 1 m gt 4.7 / 12.7 ->
  5.1 / 19.6 -> 4.2 / 13.4, 1 m fast 4.7 / 21.4 -> 5.4 / 22.9 -> 5.0 / 24.5, paper2 (benchmark_s7) gt
  13.3 / 35.0 -> 12.6 / 39.7 -> 13.4 / 43.4, at ~2.2-2.6x the default's time per SLAM frame.

The SLAM pipeline (``seedmap.slam.config.SlamAssociationConfig``) uses ``refine="field"`` and the
constant-velocity prediction by default (``stereo_carry`` off, ``stereo_prior="none"``).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal

import numpy as np
from pydantic import Field
from scipy.optimize import linear_sum_assignment

from seedmap.associate.base import FULL_RES_WIDTH, FrameFeatures, GateConfig
from seedmap.config import ConfigModel
from seedmap.errors import ConfigError, SeedmapError
from seedmap.records import Matches, StereoCalib, StereoDetections, StereoFrame

#: Cost given to gated-out pairs (removed after the assignment).
GATED = 1e9

_DIRS = ("left", "right", "top", "bottom")


class SemanticConfig(ConfigModel):
    """Parameters of the semantic cost (full-resolution pixels, i.e. a 4096 px wide image)."""

    delta_px: float = 1000.0
    eps_px: float = 15.0
    r: float = 10.0
    ratio_eps: float = 0.01
    impossible_cost: float = 1.0e4
    max_cost: float = 200.0
    neighbours: Literal["all", "overlap"] = "all"
    temporal_prediction: bool = False
    prediction_tol_px: float = 150.0
    #: "none" = the paper (one gated assignment on its cost); "consensus" / "field" = our options,
    #: see the module docstring
    refine: Literal["none", "consensus", "field"] = "none"
    consensus_k: int = 15
    consensus_tol_px: float = 4.3
    consensus_weight: float = 10.0
    consensus_iters: int = 2
    chunk: int = 512
    # refine="field" (full-resolution px unless stated)
    field_cell_px: float = 256.0
    field_bin_px: float = 3.0
    field_coarse_points: int = 1500
    field_coarse_tol_px: float = 24.0
    field_max_disparity_px: float = 1500.0
    field_max_shift_px: float = 1500.0
    field_stereo_band_px: float = 12.0
    field_stereo_sigma_px: tuple[float, float] = (4.5, 1.5)
    field_temporal_sigma_px: tuple[float, float] = (2.0, 1.0)
    field_gate_sigma: float = 3.5
    field_weight: float = 20.0
    field_k: int = 25
    field_iters: int = 4
    field_ratio: float = 0.7
    field_seed_ratio: float = 0.3
    # stereo-temporal loop (see the module docstring; needs refine="field")
    #: carry stereo matches through the left and right temporal matches of consecutive frames
    stereo_carry: bool = False
    #: gate on the loop residual of a carried pair (change of its (disparity, row offset) since the
    #: previous frame minus the local median change of its carried neighbours), full-res px (u, v)
    carry_tol_px: tuple[float, float] = (3.0, 3.0)
    #: neighbours of the local median change (leave-one-out)
    carry_k: int = 12
    #: drop temporal pairs that the loop contradicts (their stereo partners are not matched in time)
    loop_temporal: bool = True
    #: parallax test of stereo pairs along their left temporal track (0 = off): residual tolerance
    #: (full-res px), longest track remembered, shortest track tested
    parallax_tol_px: float = 4.5
    parallax_frames: int = 4
    parallax_min_frames: int = 1
    #: "verified": only stereo pairs that passed the parallax test are output (untested new pairs
    #: are kept by the matcher and carried, so they are output once tracked); "all": every pair;
    #: "frame": the loop's pairs stay internal (they check the temporal matches) and the output is
    #: the per-frame ``field`` stereo of the whole frame (costs one more stereo matching)
    stereo_output: Literal["all", "verified", "frame"] = "verified"
    #: temporal pairs whose shift disagrees with their disparity at t-1 are dropped (full-res px; 0 = off)
    temporal_parallax_tol_px: float = 4.5
    #: refinement passes of the field when it starts from the loop's fields (no coarse histogram)
    carry_field_iters: int = 3
    #: half-size (u, v) of the box in which the correction of such a field is voted for (full-res px)
    carry_init_tol_px: tuple[float, float] = (36.0, 18.0)
    #: start the field matching from the fields the loop already knows (previous temporal flow,
    #: left temporal flow for the right image, carried disparities for the new stereo pairs)
    carry_init_fields: bool = True
    #: recover a stereo pair of t-1 when only one of its keypoints was matched in time
    carry_recover: bool = True
    # stereo_prior="sgbm": dense stereo disparity as the prior of the stereo matching (needs the
    # images, i.e. SeedMatcher.features; see seedmap.associate.disparity and the module docstring)
    #: "none": the stereo prior is the keypoint field (``refine``); "sgbm": OpenCV StereoSGBM
    stereo_prior: Literal["none", "sgbm"] = "none"
    #: SGBM block size (px) and uniqueness ratio (percent)
    sgbm_block: int = Field(3, ge=1)
    sgbm_uniqueness: int = Field(5, ge=0)
    #: margin (full-res px) around the disparities of the previous frame's matches searched by SGBM
    sgbm_margin_px: float = Field(48.0, ge=0)
    #: most disparities SGBM searches (image px; its CPU time grows linearly with this)
    sgbm_max_disparities: int = Field(256, ge=16)
    #: expected spread (u, v; full-res px) of a true right keypoint around ``(u - D(u, v), v)``
    prior_sigma_px: tuple[float, float] = (2.0, 1.0)
    #: ambiguity test of the prior matching: a kept pair's residual must be below this fraction of
    #: every competitor's sharing one of its keypoints
    prior_ratio: float = Field(0.6, gt=0)
    #: left-right check (full-res px; 0 = off): also compute the right image's SGBM disparity
    #: (a second SGBM run, ~2x the prior's CPU) and drop a pair whose right keypoint's disparity
    #: points more than this away from its left keypoint (occlusions, wrong left disparities)
    sgbm_lr_tol_px: float = Field(0.0, ge=0)
    #: drop prior pairs whose disparity differs from the leave-one-out median of their ``field_k``
    #: nearest pairs' by more than this (full-res px; 0 = off): seeds far in front of / behind their
    #: neighbours, often partly occluded in one view with a biased centre
    prior_max_dev_px: float = Field(0.0, ge=0)
    #: re-assign once around ``(u - D - b, v)`` where ``b`` is the median u residual of the first
    #: assignment's pairs (SGBM's disparity is biased by ~0.2 px against the keypoint centres, and a
    #: biased prior favours pairs whose keypoint disparity errs the same way)
    prior_debias: bool = False
    # session 6: scored prior matching and appearance (NCC) verification (see the module docstring)
    #: how candidates of the dense-stereo prior are scored: "residual" (session 4: paper cost +
    #: field_weight x residual^2, ratio test on the residual) or "learned" (a logistic score of
    #: several cues, :func:`scored_prior_assign`; needs the images, i.e. SeedMatcher.features)
    #: "mlp" (session 7): a small neural network over 17 cues (:func:`mlp_prior_assign`, weights in
    #: ``score_model``)
    prior_score: Literal["residual", "learned", "mlp"] = "residual"
    #: weights of the learned score's cues (u residual^2, v residual^2 in units of prior_sigma_px,
    #: 1 - NCC, |disparity - local median of the prior| / 10 full-res px, (paper neighbour-ratio
    #: cost - 4 r) / 40 clipped at 5) and the intercept: the log-odds that a candidate is the true
    #: partner; fitted by logistic regression on the gt-oracle candidates of the tuning ranges
    #: (seeds 3 and 11, 1434 px)
    score_weights: tuple[float, float, float, float, float, float] = (-0.181, -0.39, -1.021, -1.434, -0.099, 4.891)
    #: candidate window of the learned score (normalised residual, units of prior_sigma_px)
    score_gate_sigma: float = Field(6.0, gt=0)
    #: a pair is kept when its log-odds is at least this ...
    score_min_logit: float = 1.5
    #: ... and exceeds every competitor's sharing one of its keypoints by this much
    score_margin: float = Field(1.0, ge=0)
    #: side of the NCC patches (full-res px; 31.4 = 11 px at 1434 px), rounded to an odd image size
    patch_px: float = Field(31.4, gt=0)
    # session 7: prior_score="mlp" (see the module docstring and :func:`mlp_prior_assign`)
    #: the network's weights: a JSON file written by benchmarks/fit_assoc_score.py, a file name in
    #: seedmap/associate/weights/ or a path
    score_model: str = "stereo_score_s7.json"
    #: candidate window of the network (normalised residual, units of prior_sigma_px): wider than the
    #: logistic score's, because the network separates more of the far candidates
    mlp_gate_sigma: float = Field(10.0, gt=0)
    #: a pair is kept when the network's log-odds is at least this ...
    mlp_min_logit: float = 1.0
    #: ... and exceeds every competitor's sharing one of its keypoints by this much
    mlp_margin: float = Field(1.0, ge=0)
    #: temporal verification: drop temporal pairs whose patch NCC is below this (-1 = off; needs
    #: the images, i.e. SeedMatcher.features)
    temporal_min_ncc: float = Field(-1.0, ge=-1.0, le=1.0)
    # session 8: a learned temporal score (see the module docstring and :func:`mlp_temporal_assign`)
    #: how temporal candidates are chosen: "field" (the ``refine`` method) or "mlp" (a small network
    #: over the cues of :func:`temporal_cue_candidates`; needs the images, i.e. SeedMatcher.features,
    #: and ``refine="field"``)
    temporal_score: Literal["field", "mlp"] = "field"
    #: the temporal network's weights (written by benchmarks/fit_assoc_temporal.py; a file name in
    #: seedmap/associate/weights/ or a path)
    temporal_score_model: str = "temporal_score_s8.json"
    #: candidate window around the field (normalised residual, units of field_temporal_sigma_px)
    temporal_mlp_gate_sigma: float = Field(8.0, gt=0)
    #: a temporal pair is kept when the network's log-odds is at least this ...
    temporal_mlp_min_logit: float = 1.0
    #: ... and exceeds every competitor's sharing one of its keypoints by this much
    temporal_mlp_margin: float = Field(1.0, ge=0)
    # session 9: stereo cues from the previous frame (see the module docstring and
    # :func:`history_prior_assign`; needs stereo_prior="sgbm", prior_score="mlp", temporal_score="mlp")
    #: score the stereo candidates with the previous frame's stereo pair of each tracked left keypoint
    stereo_history: bool = False
    #: the network's weights (written by benchmarks/fit_assoc_history.py; a file name in
    #: seedmap/associate/weights/ or a path)
    history_score_model: str = "stereo_history_s9.json"
    #: extra candidate window around the position predicted from the previous frame (normalised
    #: residual, units of prior_sigma_px)
    history_gate_sigma: float = Field(6.0, gt=0)
    #: a pair is kept when the network's log-odds is at least this ... (0.5 and 1.5: of the grid
    #: {0, 0.5, 1, 1.5, 2} x {0.5, 1, 1.5} the setting with the best worst-fold gated recall among those
    #: where every leave-one-range-out fold kept P >= 0.993; benchmarks/results/fit_assoc_history_s9.json)
    history_min_logit: float = 0.5
    #: ... and exceeds every competitor's sharing one of its keypoints by this much
    history_margin: float = Field(1.5, ge=0)


def full_res_scale(width: int) -> float:
    """Factor that maps pixels of an image ``width`` px wide to full-resolution pixels."""
    return FULL_RES_WIDTH / float(width)


# ----------------------------------------------------------------------------------------------
# neighbour structure and cost
# ----------------------------------------------------------------------------------------------


def _band_pairs(a: np.ndarray, eps: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every unordered index pair with ``|a_j - a_i| < eps``, listed once (sort + searchsorted, no
    N x N): ``(order, i, j)`` with ``order`` the stable argsort of ``a`` and ``i < j`` *positions in
    that sorted order* (``order[i]``, ``order[j]`` are the original indices), grouped by ``i``.
    Sorted positions let callers gather from sorted copies (contiguous reads); int32 indices."""
    order = np.argsort(a, kind="stable")
    sa = a[order]
    n = len(sa)
    it = np.int32 if n < 2**31 - 1 else np.int64
    hi = np.searchsorted(sa, sa + eps, side="left")
    cnt = np.maximum(hi - np.arange(n) - 1, 0)
    total = int(cnt.sum())
    if total == 0:
        return order, np.zeros(0, it), np.zeros(0, it)
    # j = i + 1 + (position within i's run), written as one running index minus run starts
    j = np.arange(1, total + 1, dtype=it)
    j -= np.repeat((np.cumsum(cnt) - cnt - np.arange(n)).astype(it), cnt)
    return order, np.repeat(np.arange(n, dtype=it), cnt), j


def neighbour_sums(
    kp: np.ndarray, delta: float, eps: float, valid: np.ndarray | None = None, chunk: int = 512
) -> np.ndarray:
    """``(N, 4)`` sums of distances to the left/right/top/bottom neighbour sets (pixels).

    ``kp`` (N, 2) in any pixel unit consistent with ``delta`` and ``eps``. ``valid`` (N,) bool marks
    which points may serve as neighbours (default: all). Candidate pairs come from sorting along
    the band axis (only points within ``eps`` are ever paired) and every unordered pair is
    visited once (``q`` left of ``p`` <=> ``p`` right of ``q``, same distance), so the work is
    ~N x band density / 2, not N x N. ``chunk`` is kept for API stability (unused).
    """
    kp = np.asarray(kp, np.float64).reshape(-1, 2)
    n = len(kp)
    out = np.zeros((n, 4))
    if n == 0:
        return out
    ok = np.ones(n, bool) if valid is None else np.asarray(valid, bool).reshape(-1)
    # axis 0: horizontal band (|dy| < eps) -> left / right sets; axis 1: vertical -> top / bottom
    for along, band, col in ((0, 1, 0), (1, 0, 2)):
        # pairs indexed in the band-sorted order (contiguous gathers; the sums are scattered back
        # at the end)
        order, i, j = _band_pairs(kp[:, band], eps)
        if len(i) == 0:
            continue
        sb, sa = kp[order, band], kp[order, along]
        d = sa[j]
        d -= sa[i]
        keep = np.flatnonzero((d != 0) & (np.abs(d) < delta))
        i, j, d = i[keep], j[keep], d[keep]
        dist = np.hypot(d, sb[j] - sb[i])
        # of each pair, ``first`` lies before (left of / above) ``second``: first is in second's
        # left/top set, second in first's right/bottom set
        before = d > 0
        first = np.where(before, i, j)
        second = np.where(before, j, i)
        if valid is None:
            out[order, col] = np.bincount(second, dist, minlength=n)
            out[order, col + 1] = np.bincount(first, dist, minlength=n)
        else:
            oks = ok[order]
            sel = oks[first]
            out[order, col] = np.bincount(second[sel], dist[sel], minlength=n)
            sel = oks[second]
            out[order, col + 1] = np.bincount(first[sel], dist[sel], minlength=n)
    return out


def structure_cost(
    sa: np.ndarray, sb: np.ndarray, r: float, ratio_eps: float = 0.01, impossible: float = 1.0e4
) -> np.ndarray:
    """Sum over directions of ``r * ratio_d`` between neighbour sums ``sa`` and ``sb``.

    ``sa`` and ``sb`` are ``(..., 4)`` arrays that broadcast against each other: ``(N, 1, 4)`` with
    ``(1, M, 4)`` gives the dense ``(N, M)`` matrix, ``(K, 4)`` with ``(K, 4)`` the costs of K pairs.
    """
    a = np.asarray(sa, np.float64)
    b = np.asarray(sb, np.float64)
    hi = np.maximum(a, b)
    lo = np.minimum(a, b)
    both = lo > 0
    one = (hi > 0) & ~both
    terms = np.where(one, impossible, np.where(both, r * hi / (lo + ratio_eps), 0.0))
    return terms.sum(-1)


def pair_cost(kp_a: np.ndarray, kp_b: np.ndarray, sa: np.ndarray, sb: np.ndarray, cfg: SemanticConfig,
              ia: np.ndarray | None = None, ib: np.ndarray | None = None) -> np.ndarray:
    """The paper's cost ``|y_a - y_b| + r * Σ_d ratio_d`` (full-resolution units).

    Dense ``(N, M)`` when ``ia``/``ib`` are None, else the costs of the K pairs ``(ia[k], ib[k])``.
    """
    if ia is None or ib is None:
        dy = np.abs(kp_a[:, 1][:, None] - kp_b[:, 1][None, :])
        return dy + structure_cost(sa[:, None, :], sb[None, :, :], cfg.r, cfg.ratio_eps, cfg.impossible_cost)
    dy = np.abs(kp_a[ia, 1] - kp_b[ib, 1])
    return dy + structure_cost(sa[ia], sb[ib], cfg.r, cfg.ratio_eps, cfg.impossible_cost)


def assign_sparse(n: int, m: int, ia: np.ndarray, ib: np.ndarray, cost: np.ndarray, max_cost: float) -> Matches:
    """Gated linear sum assignment on the K feasible pairs ``(ia, ib)`` with costs ``cost``.

    Equivalent to ``linear_sum_assignment`` on the dense ``n x m`` matrix with ``GATED`` at every
    infeasible entry followed by removal of gated and above-``max_cost`` pairs: the problem splits
    into connected components of the feasible bipartite graph (an optimum of the whole is an optimum
    of each component), and each component is solved densely with scipy. Keypoints without any
    feasible partner never enter the solver.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    if n == 0 or m == 0 or len(ia) == 0:
        return Matches()
    g = coo_matrix((np.ones(len(ia)), (ia, n + ib)), shape=(n + m, n + m))
    _, lab = connected_components(g, directed=False)
    comp = lab[ia]
    order = np.argsort(comp, kind="stable")
    ia, ib, cost, comp = ia[order], ib[order], cost[order], comp[order]
    bounds = np.flatnonzero(np.diff(comp)) + 1
    out_a, out_b, out_c = [], [], []
    for s, e in zip(np.r_[0, bounds], np.r_[bounds, len(comp)], strict=True):
        a, b, c = ia[s:e], ib[s:e], cost[s:e]
        ua, ra = np.unique(a, return_inverse=True)
        ub, rb = np.unique(b, return_inverse=True)
        if len(c) == 1:
            ri, ci, cc = np.zeros(1, int), np.zeros(1, int), c
        else:
            sub = np.full((len(ua), len(ub)), GATED)
            sub[ra, rb] = c
            ri, ci = linear_sum_assignment(sub)
            cc = sub[ri, ci]
        keep = (cc < GATED) & (cc <= max_cost)
        out_a.append(ua[ri[keep]])
        out_b.append(ub[ci[keep]])
        out_c.append(cc[keep])
    return Matches(np.concatenate(out_a), np.concatenate(out_b), np.concatenate(out_c))


def assign(cost: np.ndarray, feasible: np.ndarray, max_cost: float) -> Matches:
    """Dense front-end of :func:`assign_sparse`: ``cost`` (N, M) and ``feasible`` (N, M) bool."""
    ia, ib = np.nonzero(feasible)
    return assign_sparse(cost.shape[0], cost.shape[1], ia, ib, cost[ia, ib], max_cost)


def candidate_pairs(ka: np.ndarray, kb: np.ndarray, max_dy: float) -> tuple[np.ndarray, np.ndarray]:
    """Index pairs ``(i, j)`` with ``|kb[j, 1] - ka[i, 1]| <= max_dy`` without an N x M matrix."""
    order = np.argsort(kb[:, 1], kind="stable")
    vb = kb[order, 1]
    lo = np.searchsorted(vb, ka[:, 1] - max_dy, side="left")
    hi = np.searchsorted(vb, ka[:, 1] + max_dy, side="right")
    cnt = hi - lo
    total = int(cnt.sum())
    if total == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    ia = np.repeat(np.arange(len(ka)), cnt)
    offs = np.arange(total) - np.repeat(np.cumsum(cnt) - cnt, cnt)
    return ia, order[lo[ia] + offs]


def _best_per_row(ia: np.ndarray, ib: np.ndarray, c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For every distinct ``ia`` the pair with the lowest cost (O(K) after one stable sort)."""
    if len(ia) == 0:
        return ia, ib
    o = np.argsort(ia, kind="stable")
    ia, ib, c = ia[o], ib[o], c[o]
    starts = np.r_[0, np.flatnonzero(np.diff(ia)) + 1]
    counts = np.diff(np.r_[starts, len(ia)])
    mins = np.minimum.reduceat(c, starts)
    pos = np.flatnonzero(c == np.repeat(mins, counts))
    grp = np.repeat(np.arange(len(starts)), counts)[pos]
    first = pos[np.r_[True, np.diff(grp) != 0]]
    return ia[first], ib[first]


def consensus_assign(ka: np.ndarray, kb: np.ndarray, ia: np.ndarray, ib: np.ndarray, cost: np.ndarray,
                     cfg: SemanticConfig, scale: float) -> Matches:
    """Our option on top of the paper's cost: local displacement consensus.

    Panicles are rigid and smooth, so the image displacement (disparity, or the frame-to-frame
    shift) of a seed is close to that of its neighbours. Stage 1 keeps the *mutual* lowest-cost
    pairs of the paper's cost; the displacement predicted for every keypoint of A is the median
    displacement of its ``consensus_k`` nearest stage-1 matches (robust to the many stage-1
    errors); stage 2 keeps only candidates within ``consensus_tol_px`` (full-res px) of that
    prediction, adds ``consensus_weight`` x the residual (full-res px) to the paper's cost and solves
    the gated assignment; the prediction is re-estimated from the result ``consensus_iters`` times.
    """
    from scipy.spatial import cKDTree

    n, m = len(ka), len(kb)
    if len(ia) == 0:
        return Matches()
    mm = _mutual_best(ia, ib, cost, n, m)
    ma, mb = mm.idx_a, mm.idx_b
    tol = cfg.consensus_tol_px / scale
    out = Matches()
    for _ in range(max(1, cfg.consensus_iters)):
        if len(ma) == 0:
            return Matches()
        disp = kb[mb] - ka[ma]
        k = min(cfg.consensus_k, len(ma))
        _, nn = cKDTree(ka[ma]).query(ka, k)
        pred = np.median(disp[np.asarray(nn).reshape(n, k)], axis=1)
        res = np.hypot(*(kb[ib] - ka[ia] - pred[ia]).T)
        keep = res <= tol
        c2 = cost[keep] + cfg.consensus_weight * res[keep] * scale
        out = assign_sparse(n, m, ia[keep], ib[keep], c2, cfg.max_cost + cfg.consensus_weight * cfg.consensus_tol_px)
        ma, mb = out.idx_a, out.idx_b
    return out


# ----------------------------------------------------------------------------------------------
# refine="field": displacement-field prior, capped sparse assignment, consistency checks
# ----------------------------------------------------------------------------------------------


def box_pairs(pa: np.ndarray, pb: np.ndarray, half: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Index pairs ``(i, j)`` with ``|pb[j] - pa[i]| <= half`` on both axes (no N x M, no KD-tree).

    ``half`` (2,) is the half-size of the search box in the same unit as the points. The pairs come
    grouped by ``i`` in increasing order (within a group by the position of ``pb[j]``).
    Why not a KD-tree (sessions 1-4: two ``cKDTree`` builds + ``sparse_distance_matrix``, the
    largest CPU cost of the field association): with both axes divided by ``half`` the box is the
    unit max-norm ball, so the points of B sorted by (unit row, u) give, for each point of A and
    each of the two or three unit rows its box reaches, one contiguous run of candidates
    (``searchsorted`` on sorted queries); the exact test ``|pb[j] / half - pa[i] / half| <= 1``
    (the KD-tree's test, same rounding) then runs on those candidates only."""
    if len(pa) == 0 or len(pb) == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    h = np.maximum(np.asarray(half, np.float64), 1e-9)
    sa = np.asarray(pa, np.float64) / h
    sb = np.asarray(pb, np.float64) / h
    rb = np.floor(sb[:, 1])
    ra = np.floor(sa[:, 1])
    y0 = min(rb.min(), ra.min()) - 1.0
    x0 = min(sb[:, 0].min(), sa[:, 0].min()) - 2.0
    # one key per (row, u): rows lie w apart, w wider than the u range plus the search margin, so a
    # run [u - 1 - m, u + 1 + m] of one row never reaches into the next; m covers the key's rounding
    w = max(sb[:, 0].max(), sa[:, 0].max()) - x0 + 4.0
    m = 1.0 + 1e-9 + 8.0 * np.finfo(np.float64).eps * (max(rb.max(), ra.max()) - y0 + 2.0) * w
    keyb = (rb - y0) * w + (sb[:, 0] - x0)
    order = np.argsort(keyb, kind="stable")
    ks = keyb[order]
    qa = (ra - y0) * w + (sa[:, 0] - x0)
    oa = np.argsort(qa, kind="stable")  # sorted queries: searchsorted walks the array in order
    qs = qa[oa]
    lo = np.empty((len(sa), 3), np.int64)
    cnt = np.empty((len(sa), 3), np.int64)
    for c, dr in enumerate((-1.0, 0.0, 1.0)):
        base = qs + dr * w
        lo[oa, c] = np.searchsorted(ks, base - m, side="left")
        cnt[oa, c] = np.searchsorted(ks, base + m, side="right") - lo[oa, c]
    lo, cnt = lo.reshape(-1), cnt.reshape(-1)
    total = int(cnt.sum())
    if total == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    q = np.repeat(np.arange(len(lo)), cnt)
    offs = np.arange(total) - np.repeat(np.cumsum(cnt) - cnt, cnt)
    j = order[lo[q] + offs]
    i = q // 3
    ok = (np.abs(sb[j, 0] - sa[i, 0]) <= 1.0) & (np.abs(sb[j, 1] - sa[i, 1]) <= 1.0)
    return i[ok].astype(np.int64), j[ok].astype(np.int64)


def assign_capped(n: int, m: int, ia: np.ndarray, ib: np.ndarray, cost: np.ndarray, max_cost: float) -> Matches:
    """Minimum-cost matching on the sparse candidates where leaving a keypoint unmatched is allowed.

    Why: :func:`assign_sparse` (the paper's gated Hungarian) first maximises the *number* of
    assignments, so a keypoint whose true partner is missing (occlusion, detector miss, outside
    the other view) is forced onto a neighbour's partner and pushes that neighbour onto a wrong
    one. Here each keypoint may instead stay unmatched at a price of ``max_cost / 2`` per side,
    so a pair is only taken when it beats leaving both ends unmatched (``cost < max_cost``) and
    the sum over the matching is minimal. Solved exactly with
    ``scipy.sparse.csgraph.min_weight_full_bipartite_matching`` on the candidates plus one dummy
    partner per keypoint (a perfect matching then always exists).
    """
    from scipy.sparse import csr_matrix
    from scipy.sparse.csgraph import min_weight_full_bipartite_matching

    keep = np.asarray(cost) < max_cost
    ia, ib, cost = np.asarray(ia)[keep], np.asarray(ib)[keep], np.asarray(cost, np.float64)[keep]
    if n == 0 or m == 0 or len(ia) == 0:
        return Matches()
    half = 0.5 * max_cost
    rows = np.r_[ia, np.arange(n), n + np.arange(m), n + ib]
    cols = np.r_[ib, m + np.arange(n), np.arange(m), m + ia]
    # +1 on every edge: a perfect matching has exactly n + m edges, so the optimum is unchanged,
    # and no edge weight is an (implicit-looking) zero
    w = np.r_[cost, np.full(n, half), np.full(m, half), np.zeros(len(ia))] + 1.0
    g = csr_matrix((w, (rows, cols)), shape=(n + m, m + n))
    _, col = min_weight_full_bipartite_matching(g)
    a = np.flatnonzero(col[:n] < m)
    b = col[a]
    # cost of each kept pair (look-up in the candidate list)
    c = cost[candidate_positions(ia, ib, m, a, b)]
    return Matches(a.astype(np.int64), b.astype(np.int64), c)


def candidate_positions(ia: np.ndarray, ib: np.ndarray, m: int, qa: np.ndarray, qb: np.ndarray) -> np.ndarray:
    """Positions in the candidate list ``(ia, ib)`` of the pairs ``(qa, qb)``, every one of which is
    a candidate (e.g. the pairs an assignment kept); ``m`` = number of keypoints of B. One sort of
    the pair keys ``ia * m + ib`` and a binary search, no dict of pairs."""
    key = ia * m + ib
    order = np.argsort(key)
    return order[np.searchsorted(key[order], qa * m + qb)]


def coarse_field(ka: np.ndarray, kb: np.ndarray, lo: np.ndarray, hi: np.ndarray, cell: float, bin_px: float,
                 max_points: int, image_shape: tuple[float, float]) -> np.ndarray:
    """Per-keypoint displacement prior ``(N, 2)`` (u, v image px) by voting in image cells.

    Every candidate pair ``(a, b)`` whose displacement ``kb[b] - ka[a]`` lies in the box
    ``[lo, hi]`` votes in a histogram of displacements of ``a``'s image cell (``cell`` px, bins of
    ``bin_px``). True pairs of a cell share nearly one displacement (rigid, smooth panicles), wrong
    pairs spread over the box, so the peak of the histogram smoothed over 3 x 3 cells and
    neighbouring bins is the cell's displacement. At most ``max_points`` keypoints of A vote (a
    regular stride, deterministic). Cells without votes take the global peak.
    """
    from scipy.ndimage import uniform_filter

    n = len(ka)
    lo = np.asarray(lo, np.float64)
    hi = np.asarray(hi, np.float64)
    nb = np.maximum(1, np.ceil((hi - lo) / bin_px).astype(int))
    binw = (hi - lo) / nb
    stride = max(1, int(np.ceil(n / max(1, max_points))))
    sub = np.arange(0, n, stride)
    centre, half = 0.5 * (lo + hi), 0.5 * (hi - lo)
    i, j = box_pairs(ka[sub] + centre, kb, half)
    glob = centre.copy()
    ncx = int(np.ceil(image_shape[0] / cell)) + 1
    ncy = int(np.ceil(image_shape[1] / cell)) + 1
    if len(i) == 0:
        return np.tile(glob, (n, 1))
    i = sub[i]
    pcx = np.clip((ka[:, 0] // cell).astype(int), 0, ncx - 1)
    pcy = np.clip((ka[:, 1] // cell).astype(int), 0, ncy - 1)
    d = kb[j] - ka[i]
    ub = np.clip(((d - lo) / binw).astype(int), 0, nb - 1)
    flat = ((pcx * ncy + pcy)[i] * nb[0] + ub[:, 0]) * nb[1] + ub[:, 1]
    hist = np.zeros(ncx * ncy * nb[0] * nb[1], np.float32)
    cells, votes = np.unique(flat, return_counts=True)
    hist[cells] = votes
    hist = hist.reshape(ncx, ncy, nb[0], nb[1])
    g = hist.sum((0, 1))
    gi = np.unravel_index(int(np.argmax(g)), g.shape)
    glob = lo + (np.asarray(gi) + 0.5) * binw
    sm = uniform_filter(hist, size=(3, 3, 3, 3), mode="constant")
    flat_sm = sm.reshape(ncx, ncy, -1)
    best = flat_sm.argmax(-1)
    has = flat_sm.max(-1) > 0
    peak = lo + (np.stack(np.unravel_index(best, (nb[0], nb[1])), -1) + 0.5) * binw
    peak[~has] = glob
    return peak[pcx, pcy]


def local_field(ka: np.ndarray, m: Matches, kb: np.ndarray, k: int, fallback: np.ndarray) -> np.ndarray:
    """Displacement predicted for every keypoint of A from the matches ``m`` (the "seed" matches).

    At each seed match the field is the median displacement of its ``k`` nearest *other* seed
    matches (its own displacement excluded, so a match never predicts itself); every keypoint of
    A takes the field of its nearest seed match (the field is smooth at that scale, and this
    needs one k-NN query over the seeds instead of over all keypoints). ``fallback`` (N, 2)
    where fewer than 3 matches exist."""
    from scipy.spatial import cKDTree

    if len(m) < 3:
        return fallback
    pa = ka[m.idx_a]
    tree = cKDTree(pa)
    at_seed = loo_local_median(pa, kb[m.idx_b] - pa, k, tree)
    # a seed match's own keypoint is its nearest seed (distance 0) unless two seed matches share
    # a position (then the KD-tree decides, as before); only the other keypoints are queried
    near = np.full(len(ka), -1, np.int64)
    near[m.idx_a] = np.arange(len(m))
    if len(np.unique(pa.view(np.complex128))) < len(pa):
        near[:] = -1
    rest = np.flatnonzero(near < 0)
    if len(rest):
        near[rest] = np.asarray(tree.query(ka[rest], 1)[1]).reshape(-1)
    return at_seed[near]


def second_best(ia: np.ndarray, ib: np.ndarray, c: np.ndarray, m: Matches, n: int, mm: int) -> np.ndarray:
    """For each pair of ``m``: the lowest ``c`` among the *other* candidates that share its A or
    its B keypoint (``inf`` when there is none) - the competitor the ratio test compares with."""
    alt = np.full(len(m), np.inf)
    if len(m) == 0:
        return alt
    pos_a = np.full(n, -1)
    pos_a[m.idx_a] = np.arange(len(m))
    pos_b = np.full(mm, -1)
    pos_b[m.idx_b] = np.arange(len(m))
    ka, kb = pos_a[ia], pos_b[ib]
    sel = (ka >= 0) & (m.idx_b[np.maximum(ka, 0)] != ib)
    np.minimum.at(alt, ka[sel], c[sel])
    sel = (kb >= 0) & (m.idx_a[np.maximum(kb, 0)] != ia)
    np.minimum.at(alt, kb[sel], c[sel])
    return alt


def field_assign(ka: np.ndarray, kb: np.ndarray, fa: np.ndarray, fb: np.ndarray, sa: np.ndarray,
                 sb: np.ndarray, gate, lo: np.ndarray, hi: np.ndarray, sigma: np.ndarray, cfg: SemanticConfig,
                 scale: float, image_shape: tuple[float, float], fixed_v: float | None = None,
                 init: np.ndarray | None = None, iters: int | None = None) -> Matches:
    """The ``refine="field"`` association of keypoints ``ka`` (image A) with ``kb`` (image B).

    ``ka``/``kb`` image pixels, ``fa``/``fb`` the same in full-resolution units, ``sa``/``sb`` their
    neighbour sums, ``gate(ia, ib) -> bool`` the horizontal-travel gates, ``[lo, hi]`` (2,) the
    displacement box searched (image px), ``sigma`` (2,) the expected spread (u, v, image px) of a
    true displacement around the local field. ``fixed_v``: the v displacement is known (rectified
    stereo: 0, epipolar lines are image rows) and only the u field is estimated. See the module
    docstring for the steps. ``init`` (N, 2): a displacement field from elsewhere used instead of the
    coarse histogram, refined ``iters`` times (default ``cfg.field_iters``).
    """
    n, m = len(ka), len(kb)
    if n == 0 or m == 0:
        return Matches()
    pred = field_estimate(ka, kb, gate, lo, hi, sigma, cfg, scale, image_shape, fixed_v, init, iters)
    ia, ib, res = _field_candidates(ka, kb, pred, np.asarray(sigma, np.float64), gate, cfg.field_gate_sigma)
    return _assign_in_prior(fa, fb, sa, sb, ia, ib, res, n, m, cfg, cfg.field_ratio)


def field_estimate(ka: np.ndarray, kb: np.ndarray, gate, lo: np.ndarray, hi: np.ndarray, sigma: np.ndarray,
                   cfg: SemanticConfig, scale: float, image_shape: tuple[float, float], fixed_v: float | None = None,
                   init: np.ndarray | None = None, iters: int | None = None) -> np.ndarray:
    """Steps 1-2 of :func:`field_assign` (same arguments): the local displacement field (N, 2; image
    px) at every keypoint of ``ka``, from the coarse histogram (or ``init``) refined by the mutual
    best, ratio-tested candidate pairs. Also the prior of the learned temporal score
    (:func:`temporal_cue_candidates`)."""
    n, m = len(ka), len(kb)
    s_inv = 1.0 / scale
    if init is not None:
        # a field known from elsewhere (stereo-temporal loop): only its correction is voted for, in
        # a small box (far fewer candidate pairs than the whole search box)
        pred = np.array(init, np.float64).reshape(n, 2)
        r = np.asarray(cfg.carry_init_tol_px, np.float64) * s_inv
        pred = pred + coarse_field(ka + pred, kb, -r, r, cfg.field_cell_px * s_inv, cfg.field_bin_px * s_inv,
                                   cfg.field_coarse_points, image_shape)
    else:
        pred = coarse_field(ka, kb, lo, hi, cfg.field_cell_px * s_inv, cfg.field_bin_px * s_inv,
                            cfg.field_coarse_points, image_shape)
    if fixed_v is not None:
        pred[:, 1] = fixed_v
    coarse_sig = np.full(2, cfg.field_coarse_tol_px * s_inv / cfg.field_gate_sigma)
    iters = max(0, cfg.field_iters if iters is None else iters)
    for it in range(iters):
        # shrink the search window geometrically from the coarse tolerance to ``sigma``
        t = (it + 1) / (iters + 1)
        sig = coarse_sig ** (1 - t) * np.asarray(sigma) ** t if it else coarse_sig
        ia, ib, res = _field_candidates(ka, kb, pred, sig, gate, cfg.field_gate_sigma)
        # the next field comes from unambiguous mutual-best pairs only (cheap, no assignment)
        sure = _mutual_best(ia, ib, res, n, m)
        sure = _ratio_test(sure, ia, ib, res, n, m, cfg.field_seed_ratio)
        pred = local_field(ka, sure, kb, cfg.field_k, pred)
        if fixed_v is not None:
            pred[:, 1] = fixed_v
    return pred


def _assign_in_prior(fa: np.ndarray, fb: np.ndarray, sa: np.ndarray, sb: np.ndarray, ia: np.ndarray,
                     ib: np.ndarray, res: np.ndarray, n: int, m: int, cfg: SemanticConfig, ratio: float) -> Matches:
    """Final step of every prior (field or dense disparity): the paper's cost plus
    ``field_weight * res^2`` (``res`` the candidates' normalised residuals from the prior) assigned
    with :func:`assign_capped`, then the ambiguity test on the residual."""
    w = cfg.field_weight
    cost = pair_cost(fa, fb, sa, sb, cfg, ia, ib) + w * res * res
    out = assign_capped(n, m, ia, ib, cost, cfg.max_cost + w * cfg.field_gate_sigma ** 2)
    return _ratio_test(out, ia, ib, res, n, m, ratio)


def prior_assign(ka: np.ndarray, kb: np.ndarray, fa: np.ndarray, fb: np.ndarray, sa: np.ndarray, sb: np.ndarray,
                 gate, pred: np.ndarray, sigma: np.ndarray, cfg: SemanticConfig) -> Matches:
    """Association of ``ka`` with ``kb`` around a *per-keypoint* displacement prior ``pred`` (N, 2;
    image px) with per-keypoint expected spread ``sigma`` (N, 2; image px), e.g. the dense stereo
    disparity ``(-D, 0)``. Unlike :func:`field_assign` the prior is not smoothed over neighbours:
    a seed in front of or behind its panicle keeps its own displacement. Candidates within
    ``field_gate_sigma`` normalised residuals that pass ``gate``, then :func:`_assign_in_prior` with
    the ambiguity ratio ``prior_ratio``."""
    n, m = len(ka), len(kb)
    if n == 0 or m == 0:
        return Matches()
    sig = np.broadcast_to(np.asarray(sigma, np.float64), (n, 2))
    ia, ib, res = _prior_candidates(ka, kb, gate, pred, sig, cfg.field_gate_sigma)
    return _assign_in_prior(fa, fb, sa, sb, ia, ib, res, n, m, cfg, cfg.prior_ratio)


def _prior_candidates(ka: np.ndarray, kb: np.ndarray, gate, pred: np.ndarray, sig: np.ndarray,
                      gate_sigma: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Candidate pairs ``(ia, ib)`` of a per-keypoint prior ``pred`` (N, 2; image px) that pass
    ``gate`` and lie within ``gate_sigma`` normalised residuals (``sig``, N x 2 px), with those
    residuals; shared by :func:`prior_assign` and :func:`scored_prior_assign`."""
    ia, ib = box_pairs(ka + pred, kb, gate_sigma * sig.max(0))
    ok = gate(ia, ib)
    ia, ib = ia[ok], ib[ok]
    r = (kb[ib] - ka[ia] - pred[ia]) / sig[ia]
    res = np.hypot(r[:, 0], r[:, 1])
    ok = res <= gate_sigma
    return ia[ok], ib[ok], res[ok]


def score_features(ka: np.ndarray, kb: np.ndarray, ia: np.ndarray, ib: np.ndarray, pred: np.ndarray,
                   sig: np.ndarray, local_pred: np.ndarray, ncc: np.ndarray, sa: np.ndarray, sb: np.ndarray,
                   cfg: SemanticConfig, scale: float) -> np.ndarray:
    """``(K, 5)`` cues of the candidate pairs ``(ka[ia], kb[ib])`` for :func:`scored_prior_assign`:
    squared u and v residuals from the prior ``pred`` (N, 2; image px) in units of ``sig`` (N, 2),
    ``1 - ncc``, the u distance of the candidate displacement from ``local_pred`` (N, 2; the prior
    smoothed over the neighbours) in tens of full-res px (clipped at 4; a seed whose displacement
    disagrees with both its own prior and its neighbours' is rarely right), and the paper's
    neighbour-ratio cost above its floor of 4 r, in units of 40 and clipped at 5."""
    r = (kb[ib] - ka[ia] - pred[ia]) / sig[ia]
    dev = np.abs(kb[ib, 0] - ka[ia, 0] - local_pred[ia, 0]) * scale
    pc = structure_cost(sa[ia], sb[ib], cfg.r, cfg.ratio_eps, cfg.impossible_cost) - 4.0 * cfg.r
    return np.c_[r[:, 0] ** 2, r[:, 1] ** 2, 1.0 - np.asarray(ncc, np.float64), np.minimum(dev, 40.0) / 10.0,
                 np.minimum(pc, 200.0) / 40.0]


def scored_prior_assign(ka: np.ndarray, kb: np.ndarray, sa: np.ndarray, sb: np.ndarray, gate, pred: np.ndarray,
                        sig: np.ndarray, desc_a: np.ndarray, desc_b: np.ndarray, cfg: SemanticConfig,
                        scale: float) -> Matches:
    """Association around a per-keypoint displacement prior ``pred`` (N, 2; image px, e.g. the dense
    stereo disparity ``(-D, 0)``) scored by several cues at once (``prior_score="learned"``).

    Why (session 6): with the residual from the prior alone, 7 % of the true stereo pairs were lost
    to the ratio test and 2 % of the output was wrong (slam_r1, gt oracle): a seed's neighbours lie
    ~3 px away, and the prior is off by more than that for seeds on a depth edge. Other cues
    separate them: the patch NCC (image appearance, ``desc_a``/``desc_b`` from
    :func:`seedmap.associate.disparity.patch_descriptors`), the v residual (rectified rows), the
    candidate's disagreement with its neighbours' prior and the paper's neighbour cost. Their
    weighted sum (``score_weights``, a logistic regression fitted on the tuning ranges) is the
    log-odds ``t`` that a candidate is the true partner. Candidates within ``score_gate_sigma``
    normalised residuals (wider than the residual method's gate: the score, not the window, decides)
    are assigned one-to-one minimising ``-t`` (:func:`assign_capped`, a keypoint may stay unmatched,
    a pair needs ``t >= score_min_logit``), and a pair is kept only when its ``t`` beats every
    competitor sharing one of its keypoints by ``score_margin`` (ambiguity test)."""
    n, m = len(ka), len(kb)
    if n == 0 or m == 0:
        return Matches()
    sig = np.broadcast_to(np.asarray(sig, np.float64), (n, 2))
    ia, ib, _ = _prior_candidates(ka, kb, gate, pred, sig, cfg.score_gate_sigma)
    if len(ia) == 0:
        return Matches()
    local_pred = field_at(ka, pred, ka, cfg.field_k) if n >= 3 else pred
    from seedmap.associate.disparity import patch_ncc

    x = score_features(ka, kb, ia, ib, pred, sig, local_pred, patch_ncc(desc_a, desc_b, ia, ib), sa, sb, cfg, scale)
    w = np.asarray(cfg.score_weights, np.float64)
    t = x @ w[:-1] + w[-1]
    return assign_logits(ia, ib, t, n, m, cfg.score_min_logit, cfg.score_margin)


def assign_logits(ia: np.ndarray, ib: np.ndarray, t: np.ndarray, n: int, m: int, min_logit: float,
                  margin: float) -> Matches:
    """One-to-one assignment of scored candidates ``(ia, ib)`` maximising the summed log-odds ``t``
    (:func:`assign_capped` on ``-t``; a keypoint may stay unmatched, a pair needs ``t >= min_logit``),
    then the ambiguity test: a kept pair's ``t`` must beat every competitor sharing one of its
    keypoints by ``margin``. ``Matches.cost`` is ``top - t`` (lower is better)."""
    if len(ia) == 0:
        return Matches()
    # costs must be positive for the matching: offset by the largest possible log-odds
    top = float(max(t.max(), min_logit)) + 1.0
    cost = top - t
    out = assign_capped(n, m, ia, ib, cost, top - min_logit + 1e-9)
    if len(out) == 0:
        return out
    pos = candidate_positions(ia, ib, m, out.idx_a, out.idx_b)
    alt = second_best(ia, ib, cost, out, n, m)
    keep = cost[pos] + margin < alt
    return Matches(out.idx_a[keep], out.idx_b[keep], out.cost[keep])


# ----------------------------------------------------------------------------------------------
# session 7: a small network over more cues (prior_score="mlp")
# ----------------------------------------------------------------------------------------------

#: The cues :func:`cue_features` computes for every candidate pair, in column order (see there).
CUE_NAMES = ("u_res2", "v_res2", "ncc", "neighbour_dev", "paper_cost", "ncc_small", "ncc_large", "ncc_colour",
             "chroma", "brightness", "depth_edge", "occlusion", "area_ratio", "n_cand_left", "n_cand_right",
             "log_area_left", "log_area_right")
#: patch sides (full-res px) of the small and large grey NCC (7 and 19 px at 1434 px); the middle
#: one is ``SemanticConfig.patch_px`` (11 px), the colour NCC uses that one too
CUE_PATCH_SMALL_PX = 20.0
CUE_PATCH_LARGE_PX = 54.0
#: half-width (full-res px) of the row segment of the depth-edge cue (6 px at 1434 px) and reach of
#: the occlusion cue (48 px at 1434 px)
CUE_EDGE_HALF_PX = 17.0
CUE_OCCLUSION_REACH_PX = 137.0


def patch_side(width: int, full_res_px: float) -> int:
    """Side (image px) of a ``full_res_px`` patch at an image ``width`` px wide: rounded, odd, >= 3."""
    k = int(round(full_res_px / full_res_scale(width)))
    return max(3, k + 1 - k % 2)


def cue_patch_sizes(width: int, patch_px: float) -> tuple[int, int, int]:
    """Odd patch sides (image px) of the small, middle and large NCC at an image ``width`` px wide."""
    return patch_side(width, CUE_PATCH_SMALL_PX), patch_side(width, patch_px), patch_side(width, CUE_PATCH_LARGE_PX)


@dataclass
class ImageCues:
    """Per-keypoint appearance of one image for :func:`cue_features`: grey patch descriptors by
    side (image px), colour descriptors, chromaticity (N, 3), brightness (N,) and the detector's
    ellipse area (major x minor axis, image px^2; NaN = unknown)."""

    patches: dict[int, np.ndarray]
    colour: np.ndarray
    chroma: np.ndarray
    brightness: np.ndarray
    area: np.ndarray


@dataclass
class StereoCues:
    """What the ``mlp`` score sees besides the keypoints: both images' :class:`ImageCues` and the
    left image's dense disparity map (image px, NaN = none)."""

    left: ImageCues
    right: ImageCues
    disparity_image: np.ndarray


def image_cues(image: np.ndarray, kp: np.ndarray, ellipses: np.ndarray | None, width: int,
               patch_px: float) -> ImageCues:
    """:class:`ImageCues` of the keypoints ``kp`` (N, 2) of one image (three grey patch sizes from
    :func:`cue_patch_sizes`, colour patches of the middle size, 5 x 5 px mean colour)."""
    from seedmap.associate.disparity import colour_descriptors, grey_image, mean_colour, patch_descriptors

    kp = np.asarray(kp, np.float64).reshape(-1, 2)
    sizes = cue_patch_sizes(width, patch_px)
    grey = grey_image(image)  # once for the three sizes
    patches = {k: patch_descriptors(grey, kp, k) for k in sorted(set(sizes))}
    chroma, bright = mean_colour(image, kp, 2)
    if ellipses is not None and len(ellipses) == len(kp):
        e = np.asarray(ellipses, np.float64).reshape(-1, 5)
        area = e[:, 2] * e[:, 3]
    else:
        area = np.full(len(kp), np.nan)
    return ImageCues(patches, colour_descriptors(image, kp, sizes[1]), chroma, bright, area)


def cue_features(ka: np.ndarray, kb: np.ndarray, ia: np.ndarray, ib: np.ndarray, pred: np.ndarray,
                 sig: np.ndarray, local_pred: np.ndarray, sa: np.ndarray, sb: np.ndarray, cues: StereoCues,
                 cfg: SemanticConfig, width: int) -> np.ndarray:
    """``(K, len(CUE_NAMES))`` cues of the stereo candidates ``(ka[ia], kb[ib])`` around the prior
    ``pred`` (image px) for the ``mlp`` score, columns as named in :data:`CUE_NAMES`:

    * the five of :func:`score_features` (with the middle-size grey NCC);
    * ``ncc_small`` / ``ncc_large``: 1 - grey NCC of 7 and 19 px patches (1434 px image): the seed
      itself and a wider neighbourhood; ``ncc_colour``: 1 - colour NCC (11 px);
    * ``chroma``: L1 distance of the 5 x 5 px chromaticities, ``brightness``: |log ratio| of their
      brightness (the two views see a seed from 11 cm apart; a neighbour differs more);
    * ``depth_edge``: range of the dense disparity along the left keypoint's row (+- 6 px), in 30
      full-res px, capped at 3: at a depth edge SGBM often gives a seed the occluder's disparity;
    * ``occlusion``: :func:`seedmap.associate.disparity.occlusion_margin` of the candidate's disparity
      (full-res px / 15, clipped to -0.4..2): a nearer surface covering the left keypoint's position
      in the right image (its partner hidden);
    * ``area_ratio``: |log ratio| of the two ellipse areas (a full seed paired with a sliver);
    * ``n_cand_left`` / ``n_cand_right``: candidates of each keypoint in the window (crowding);
    * ``log_area_left`` / ``log_area_right``: log(1 + ellipse area in full-res px^2) (partly
      occluded seeds are small and their prior least reliable).

    Missing ellipse areas give 0 for the three area cues."""
    from seedmap.associate.disparity import disparity_edge_range, occlusion_margin

    s = full_res_scale(width)
    a = _pair_appearance(cues.left, cues.right, ka, kb, ia, ib, width, cfg.patch_px)
    base = score_features(ka, kb, ia, ib, pred, sig, local_pred, a["ncc"], sa, sb, cfg, s)
    dimg = cues.disparity_image
    half = max(1, int(round(CUE_EDGE_HALF_PX / s)))
    edge = disparity_edge_range(dimg, ka, half)[ia] * s
    occ = occlusion_margin(dimg, ka[ia, 0], ka[ia, 1], ka[ia, 0] - kb[ib, 0], max(2, int(round(CUE_OCCLUSION_REACH_PX / s))))
    occ = np.clip(np.where(np.isfinite(occ), occ * s, -6.0), -6.0, 30.0) / 15.0
    return np.c_[base, 1.0 - a["ncc_small"], 1.0 - a["ncc_large"], 1.0 - a["ncc_colour"], a["chroma"], a["brightness"],
                 np.minimum(edge, 90.0) / 30.0, occ, a["area_ratio"], a["n_a"], a["n_b"], a["log_area_a"],
                 a["log_area_b"]]


def _pair_appearance(L: ImageCues, R: ImageCues, ka: np.ndarray, kb: np.ndarray, ia: np.ndarray, ib: np.ndarray,
                     width: int, patch_px: float) -> dict[str, np.ndarray]:
    """Appearance cues of the candidate pairs ``(ka[ia], kb[ib])`` shared by the stereo
    (:func:`cue_features`) and temporal (:func:`temporal_cue_candidates`) scores: grey NCC at the
    three patch sizes, colour NCC, chromaticity L1 distance, |log brightness ratio|, |log ellipse
    area ratio| (0 where unknown), each keypoint's number of candidates (crowding) and
    log(1 + ellipse area in full-res px^2) (0 where unknown)."""
    from seedmap.associate.disparity import patch_ncc

    s = full_res_scale(width)
    small, mid, large = cue_patch_sizes(width, patch_px)
    al = np.nan_to_num(L.area[ia] * s * s, nan=-1.0)
    ar = np.nan_to_num(R.area[ib] * s * s, nan=-1.0)
    known = (al >= 0) & (ar >= 0)
    return {
        "ncc": patch_ncc(L.patches[mid], R.patches[mid], ia, ib),
        "ncc_small": patch_ncc(L.patches[small], R.patches[small], ia, ib),
        "ncc_large": patch_ncc(L.patches[large], R.patches[large], ia, ib),
        "ncc_colour": patch_ncc(L.colour, R.colour, ia, ib),
        "chroma": np.abs(L.chroma[ia] - R.chroma[ib]).sum(1),
        "brightness": np.abs(np.log((L.brightness[ia] + 1.0) / (R.brightness[ib] + 1.0))),
        "area_ratio": np.where(known, np.abs(np.log((np.maximum(al, 0) + 1.0) / (np.maximum(ar, 0) + 1.0))), 0.0),
        "n_a": np.bincount(ia, minlength=len(ka))[ia].astype(np.float64),
        "n_b": np.bincount(ib, minlength=len(kb))[ib].astype(np.float64),
        "log_area_a": np.where(al >= 0, np.log1p(np.maximum(al, 0)), 0.0),
        "log_area_b": np.where(ar >= 0, np.log1p(np.maximum(ar, 0)), 0.0),
    }


@dataclass
class ScoreModel:
    """A small fully connected network (ReLU) giving the log-odds that a candidate is the true
    partner from the cues named ``features`` (a subset of :data:`CUE_NAMES`), standardised with
    ``mean``/``std``. ``layers``: (weight (out, in), bias (out,)) per layer; the last layer has one
    output. Written by ``benchmarks/fit_assoc_score.py`` as JSON (:meth:`save` / :meth:`load`).
    ``kind``: "stereo" (cues of :data:`CUE_NAMES`), "temporal" (:data:`TEMPORAL_CUE_NAMES`,
    session 8, ``benchmarks/fit_assoc_temporal.py``) or "stereo_history" (:data:`CUE_NAMES` +
    :data:`HISTORY_CUE_NAMES`, session 9, ``benchmarks/fit_assoc_history.py``)."""

    features: tuple[str, ...]
    mean: np.ndarray
    std: np.ndarray
    layers: list[tuple[np.ndarray, np.ndarray]]
    info: dict
    kind: str = "stereo"

    @property
    def cue_names(self) -> tuple[str, ...]:
        """The column names of the cue matrices this model reads."""
        return _CUE_NAMES_OF_KIND[self.kind]

    def logits(self, cues: np.ndarray) -> np.ndarray:
        """Log-odds (K,) of the candidates whose cue rows are ``cues`` (K, len(cue_names)):
        :func:`cue_features` rows for a stereo model, :func:`temporal_cue_candidates` rows for a
        temporal one."""
        names = self.cue_names
        cols = [names.index(f) for f in self.features]
        h = (np.asarray(cues, np.float64)[:, cols] - self.mean) / self.std
        for k, (w, b) in enumerate(self.layers):
            h = h @ w.T + b
            if k + 1 < len(self.layers):
                np.maximum(h, 0.0, out=h)
        return h[:, 0]

    def save(self, path) -> None:
        import json
        from pathlib import Path

        from seedmap.io.atomic import atomic_write_text

        d = {"kind": self.kind, "features": list(self.features), "mean": self.mean.tolist(), "std": self.std.tolist(),
             "layers": [{"weight": w.tolist(), "bias": b.tolist()} for w, b in self.layers], "info": self.info}
        atomic_write_text(Path(path), json.dumps(d) + "\n")

    @staticmethod
    def load(name: str) -> ScoreModel:
        """From a path, or a file name in seedmap/associate/weights/."""
        import json
        from pathlib import Path

        p = Path(name)
        if not p.is_file():
            p = Path(__file__).parent / "weights" / name
        if not p.is_file():
            raise SeedmapError(f"{name}: association score model not found (a path or a file in {p.parent})")
        try:
            d = json.loads(p.read_text())
            feats = tuple(d["features"])
            kind = str(d.get("kind", "stereo"))
            if kind not in _CUE_NAMES_OF_KIND:
                raise ValueError(f"unknown kind {kind!r}")
            bad = [f for f in feats if f not in _CUE_NAMES_OF_KIND[kind]]
            if bad:
                raise ValueError(f"unknown cues {bad}")
            layers = [(np.asarray(l["weight"], np.float64), np.asarray(l["bias"], np.float64)) for l in d["layers"]]
            model = ScoreModel(feats, np.asarray(d["mean"], np.float64), np.asarray(d["std"], np.float64), layers,
                               dict(d.get("info", {})), kind)
        except (ValueError, KeyError, TypeError) as e:
            raise SeedmapError(f"{p}: not an association score model ({e})") from None
        return model


_MODELS: dict[str, ScoreModel] = {}


def _cue_names_of_kind() -> dict[str, tuple[str, ...]]:
    return {"stereo": CUE_NAMES, "temporal": TEMPORAL_CUE_NAMES, "stereo_history": CUE_NAMES + HISTORY_CUE_NAMES}


def score_model(name: str, kind: str = "stereo") -> ScoreModel:
    """:meth:`ScoreModel.load`, cached per name (the matcher calls it every frame); a model of another
    ``kind`` than asked for is a user error."""
    if name not in _MODELS:
        _MODELS[name] = ScoreModel.load(name)
    model = _MODELS[name]
    if model.kind != kind:
        raise SeedmapError(f"{name}: a {model.kind} association score model, but a {kind} one is needed")
    return model


def stereo_cue_candidates(kl: np.ndarray, kr: np.ndarray, width: int, gates: GateConfig | None,
                          cfg: SemanticConfig, disparity: np.ndarray, cues: StereoCues,
                          sums: tuple[np.ndarray, np.ndarray] | None = None
                          ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Candidates ``(ia, ib)`` of the dense-disparity prior within ``mlp_gate_sigma`` and their
    :func:`cue_features` rows: what :func:`mlp_prior_assign` scores, and what
    ``benchmarks/fit_assoc_score.py`` labels with ground truth to fit the network (one code path)."""
    c = _dense_prior_candidates(kl, kr, width, gates, cfg, disparity, sums)
    if c is None or len(c.ia) == 0:
        return _no_candidates(len(CUE_NAMES))
    return c.ia, c.ib, c.cue_rows(c.ia, c.ib, cues, cfg, width)


@dataclass
class _DensePriorCandidates:
    """Where both learned stereo scores start (:func:`stereo_cue_candidates`,
    :func:`history_cue_candidates`): the keypoints (N x 2, M x 2; image px, float64), the full-res
    scale ``s``, their neighbour sums (full-res), the dense-disparity prior ``pred`` / ``sig`` (N x 2
    each, image px; :func:`_disparity_prior`), the stereo gate and the gated candidates ``(ia, ib)``
    within ``mlp_gate_sigma`` of the prior."""

    kl: np.ndarray
    kr: np.ndarray
    s: float
    sums: tuple[np.ndarray, np.ndarray]
    pred: np.ndarray
    sig: np.ndarray
    gate: Callable[[np.ndarray, np.ndarray], np.ndarray]
    ia: np.ndarray
    ib: np.ndarray

    def cue_rows(self, ia: np.ndarray, ib: np.ndarray, cues: StereoCues, cfg: SemanticConfig,
                 width: int) -> np.ndarray:
        """:func:`cue_features` rows of the candidates ``(ia, ib)`` (the neighbours' prediction is
        the prior's median over the ``field_k`` nearest left keypoints)."""
        local_pred = field_at(self.kl, self.pred, self.kl, cfg.field_k)
        return cue_features(self.kl, self.kr, ia, ib, self.pred, self.sig, local_pred, self.sums[0], self.sums[1],
                            cues, cfg, width)


def _dense_prior_candidates(kl: np.ndarray, kr: np.ndarray, width: int, gates: GateConfig | None,
                            cfg: SemanticConfig, disparity: np.ndarray,
                            sums: tuple[np.ndarray, np.ndarray] | None) -> _DensePriorCandidates | None:
    """The setup shared by the learned stereo scores (:class:`_DensePriorCandidates`); None when
    nothing can be scored (fewer than 3 left keypoints, no right keypoint, fewer than 3 known
    disparities). ``sums``: precomputed full-res neighbour sums of (left, right), else computed."""
    cfg, g, kl, kr, s = _pair_inputs(kl, kr, width, gates, cfg)
    if len(kl) < 3 or len(kr) == 0:
        return None
    sums = _full_res_sums(kl, kr, s, cfg, sums)
    prior = _disparity_prior(kl, disparity, cfg, s)
    if prior is None:
        return None
    pred, sig = prior
    gate = _stereo_gate_fn(kl, kr, g, width)
    ia, ib, _ = _prior_candidates(kl, kr, gate, pred, sig, cfg.mlp_gate_sigma)
    return _DensePriorCandidates(kl, kr, s, sums, pred, sig, gate, ia, ib)


def _pair_inputs(kp_a: np.ndarray, kp_b: np.ndarray, width: int, gates: GateConfig | None,
                 cfg: SemanticConfig | None) -> tuple[SemanticConfig, GateConfig, np.ndarray, np.ndarray, float]:
    """What every association of two keypoint sets starts from: ``cfg`` (default
    :class:`SemanticConfig`), the gates scaled to the image ``width`` (default :class:`GateConfig`),
    both keypoint sets as (N, 2) float64 image px and :func:`full_res_scale` of the width."""
    g = (gates or GateConfig()).scaled(width)
    ka = np.asarray(kp_a, np.float64).reshape(-1, 2)
    kb = np.asarray(kp_b, np.float64).reshape(-1, 2)
    return cfg or SemanticConfig(), g, ka, kb, full_res_scale(width)


def _full_res_sums(ka: np.ndarray, kb: np.ndarray, s: float, cfg: SemanticConfig,
                   sums: tuple[np.ndarray, np.ndarray] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """``sums`` when given (a cache), else the :func:`neighbour_sums` of ``ka`` and ``kb`` (image px)
    in full-resolution units (``s`` = :func:`full_res_scale`), with every keypoint a neighbour."""
    if sums is not None:
        return sums
    return (neighbour_sums(ka * s, cfg.delta_px, cfg.eps_px, chunk=cfg.chunk),
            neighbour_sums(kb * s, cfg.delta_px, cfg.eps_px, chunk=cfg.chunk))


def _no_candidates(ncol: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The empty ``(ia, ib, cue rows)`` of the cue-candidate functions (``ncol`` cue columns)."""
    return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, ncol))


def mlp_prior_assign(kl: np.ndarray, kr: np.ndarray, width: int, gates: GateConfig | None, cfg: SemanticConfig,
                     disparity: np.ndarray, cues: StereoCues,
                     sums: tuple[np.ndarray, np.ndarray] | None = None) -> Matches:
    """Stereo association around the dense disparity prior scored by a small network
    (``prior_score="mlp"``, session 7).

    Why: the session-6 logistic score of five cues left 1.6 % wrong pairs and 11 % of the gated
    true pairs unmatched on the seed-11 range. Its wrong pairs are mostly *cross-occlusions*: a
    seed seen only in the left image (its right view hidden by a nearer seed or leaf, or a sliver
    the detector does not emit; 61 % of the wrong pairs) paired with a neighbour at nearly the same
    depth (median true-disparity difference 0.35 px; most of them have no left keypoint themselves),
    at the position SGBM predicts because SGBM gives the left seed the occluder's disparity (median
    5.9 px too large there, vs 0.28 px for true pairs). No single cue separates them (the occlusion test
    on the left disparity map alone rejects 3 % of the true pairs for 11 % of the wrong ones), but
    together - appearance at three scales and in colour, depth-edge and occlusion cues, ellipse
    sizes, crowding - a network with two small hidden layers does (candidates of the rendered
    tuning ranges, ground-truth labels). Candidates within ``mlp_gate_sigma``, assignment and
    ambiguity test as :func:`assign_logits` with ``mlp_min_logit`` / ``mlp_margin``."""
    kl = np.asarray(kl, np.float64).reshape(-1, 2)
    kr = np.asarray(kr, np.float64).reshape(-1, 2)
    ia, ib, x = stereo_cue_candidates(kl, kr, width, gates, cfg, disparity, cues, sums)
    if len(ia) == 0:
        return Matches()
    t = score_model(cfg.score_model).logits(x)
    return assign_logits(ia, ib, t, len(kl), len(kr), cfg.mlp_min_logit, cfg.mlp_margin)


# ----------------------------------------------------------------------------------------------
# session 8: a learned temporal candidate score (temporal_score="mlp")
# ----------------------------------------------------------------------------------------------

#: The cues :func:`temporal_cue_candidates` computes for every temporal candidate pair, in column
#: order (see there).
TEMPORAL_CUE_NAMES = ("u_res2", "v_res2", "ncc", "parallax_res", "paper_cost", "ncc_small", "ncc_large",
                      "ncc_colour", "chroma", "brightness", "area_ratio", "n_cand_prev", "n_cand_cur",
                      "log_area_prev", "log_area_cur", "disp_change", "disp_dev", "u_res", "v_res")


@dataclass
class TemporalInputs:
    """What the learned temporal score sees of one frame's left image: :class:`ImageCues` of its
    keypoints and the disparity of each (image px, NaN = unknown; the dense SGBM disparity when the
    ``sgbm`` prior ran, else the disparity of the keypoint's stereo match)."""

    cues: ImageCues
    disparity: np.ndarray


def _filled_disparity(kp: np.ndarray, d: np.ndarray, k: int) -> np.ndarray | None:
    """``d`` with unknown (NaN) entries replaced by the median of the ``k`` nearest known ones;
    None with fewer than 3 known."""
    d = np.asarray(d, np.float64).reshape(-1).copy()
    known = np.isfinite(d)
    if known.sum() < 3:
        return None
    if not known.all():
        d[~known] = field_at(kp[known], d[known, None], kp[~known], k)[:, 0]
    return d


def temporal_cue_candidates(ka: np.ndarray, kb: np.ndarray, width: int, gates: GateConfig | None,
                            cfg: SemanticConfig, prev: TemporalInputs, cur: TemporalInputs,
                            predicted_shift: float | None = None, predicted_shift_v: float | None = None,
                            sums: tuple[np.ndarray, np.ndarray] | None = None
                            ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Temporal candidates ``(ia, ib)`` (previous left ``ka`` <-> current left ``kb``, image px) and
    their cue rows (columns :data:`TEMPORAL_CUE_NAMES`): what :func:`mlp_temporal_assign` scores and
    what ``benchmarks/fit_assoc_temporal.py`` labels with ground truth (one code path).

    The prior is the ``field`` matching's local shift field (:func:`field_estimate`, the same
    search box, gates and refinements as ``refine="field"``); candidates lie within
    ``temporal_mlp_gate_sigma`` normalised residuals (units of ``field_temporal_sigma_px``) of it.
    Cues: squared and absolute u / v residuals from the field; ``parallax_res``: the u residual
    after the parallax correction ``alpha * (D - D_local)`` (a static seed shifts by
    ``alpha * disparity + beta`` between frames, so a seed nearer or farther than its neighbours
    leaves the smooth field by ``alpha`` times its disparity deviation; ``alpha`` = median field
    shift / median disparity of the frame), in the same units, absolute, capped at 20;
    ``disp_change``: |disparity at t - disparity at t-1| (the camera travels along the rows, so a
    seed's depth barely changes; full-res px / 10, capped at 6); ``disp_dev``: |D - D_local| of the
    previous keypoint (full-res px / 10, capped at 6); the paper's neighbour cost (as
    :func:`score_features`) and the appearance cues of :func:`_pair_appearance` between the two
    frames' left images. Why: the ``field`` path keeps a pair only when its residual is the best by
    a ratio (``field_ratio``) inside 3.5 sigma; seeds at a depth edge or with a moved centre fail
    that test although their appearance and depth identify them."""
    cfg, g, ka, kb, s = _pair_inputs(ka, kb, width, gates, cfg)
    empty = _no_candidates(len(TEMPORAL_CUE_NAMES))
    if len(ka) < 3 or len(kb) < 3:
        return empty
    sums = _full_res_sums(ka, kb, s, cfg, sums)
    gate, lo, hi, extent = _temporal_search(ka, kb, width, g, cfg, predicted_shift, predicted_shift_v)
    sigma = np.asarray(cfg.field_temporal_sigma_px, np.float64) / s
    pred = field_estimate(ka, kb, gate, lo, hi, sigma, cfg, s, extent)
    ia, ib, _ = _field_candidates(ka, kb, pred, sigma, gate, cfg.temporal_mlp_gate_sigma)
    if len(ia) == 0:
        return empty
    r = (kb[ib] - ka[ia] - pred[ia]) / sigma
    da = _filled_disparity(ka, prev.disparity, cfg.field_k)
    db = _filled_disparity(kb, cur.disparity, cfg.field_k)
    if da is not None and db is not None:
        d_loc = field_at(ka, da[:, None], ka, cfg.field_k)[:, 0]
        alpha = float(np.median(pred[:, 0]) / max(float(np.median(da)), 1e-6))
        par = r[:, 0] - alpha * (da[ia] - d_loc[ia]) / sigma[0]
        change = np.minimum(np.abs(db[ib] - da[ia]) * s, 60.0) / 10.0
        dev = np.minimum(np.abs(da[ia] - d_loc[ia]) * s, 60.0) / 10.0
    else:  # no disparity: the parallax cues say nothing
        par, change, dev = r[:, 0], np.zeros(len(ia)), np.zeros(len(ia))
    pc = structure_cost(sums[0][ia], sums[1][ib], cfg.r, cfg.ratio_eps, cfg.impossible_cost) - 4.0 * cfg.r
    a = _pair_appearance(prev.cues, cur.cues, ka, kb, ia, ib, width, cfg.patch_px)
    x = np.c_[r[:, 0] ** 2, r[:, 1] ** 2, 1.0 - a["ncc"], np.minimum(np.abs(par), 20.0),
              np.minimum(pc, 200.0) / 40.0, 1.0 - a["ncc_small"], 1.0 - a["ncc_large"], 1.0 - a["ncc_colour"],
              a["chroma"], a["brightness"], a["area_ratio"], a["n_a"], a["n_b"], a["log_area_a"], a["log_area_b"],
              change, dev, np.abs(r[:, 0]), np.abs(r[:, 1])]
    return ia, ib, x


def mlp_temporal_assign(ka: np.ndarray, kb: np.ndarray, width: int, gates: GateConfig | None, cfg: SemanticConfig,
                        prev: TemporalInputs, cur: TemporalInputs, predicted_shift: float | None = None,
                        predicted_shift_v: float | None = None,
                        sums: tuple[np.ndarray, np.ndarray] | None = None) -> Matches:
    """Temporal association (previous left ``ka`` <-> current left ``kb``) scored by a small network
    (``temporal_score="mlp"``, session 8): the candidates of :func:`temporal_cue_candidates`, the
    log-odds of ``temporal_score_model``, one-to-one assignment and ambiguity test as
    :func:`assign_logits` with ``temporal_mlp_min_logit`` / ``temporal_mlp_margin``."""
    ka = np.asarray(ka, np.float64).reshape(-1, 2)
    kb = np.asarray(kb, np.float64).reshape(-1, 2)
    ia, ib, x = temporal_cue_candidates(ka, kb, width, gates, cfg, prev, cur, predicted_shift, predicted_shift_v,
                                        sums)
    if len(ia) == 0:
        return Matches()
    t = score_model(cfg.temporal_score_model, "temporal").logits(x)
    return assign_logits(ia, ib, t, len(ka), len(kb), cfg.temporal_mlp_min_logit, cfg.temporal_mlp_margin)


# ----------------------------------------------------------------------------------------------
# session 9: stereo cues from the previous frame (stereo_history=True)
# ----------------------------------------------------------------------------------------------

#: The cues :func:`history_cue_candidates` appends to :data:`CUE_NAMES`, in column order (see there).
HISTORY_CUE_NAMES = ("has_history", "hist_u_res", "hist_v_res", "hist_ncc_right", "hist_ncc_right_large",
                     "hist_disp_dev")


@dataclass
class StereoHistory:
    """What the stereo score of frame t sees of frame t-1: its keypoints (image px), its stereo
    matches, the temporal matches ``left(t-1) -> left(t)`` (computed *before* the stereo matching of
    t, from the dense disparity, :class:`TemporalInputs`) and the :class:`ImageCues` of its right
    keypoints."""

    kp_left: np.ndarray
    kp_right: np.ndarray
    stereo: Matches
    temporal: Matches
    right: ImageCues


def history_prior(kl: np.ndarray, hist: StereoHistory, disparity: np.ndarray, width: int, k: int
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per left keypoint of frame t (``kl``, N x 2 image px): the right keypoint of t-1 it is
    tracked to (through the temporal match and the stereo match of t-1; -1 = none), the disparity
    predicted from t-1 (image px; NaN = no history), the predicted row offset ``v_right - v_left``
    (image px) and the deviation of the dense disparity from the predicted one (image px, NaN).

    The predicted disparity is the t-1 pair's disparity plus the local median change of the
    tracked seeds' dense disparity (median of ``D_t - d_{t-1}`` over the ``k`` nearest tracked
    keypoints): the camera travels along the rows, so a seed's disparity barely changes, and the
    local median also absorbs the dense disparity's small bias against the keypoint centres."""
    n = len(kl)
    prev_right = np.full(n, -1, np.int64)
    d_hist = np.full(n, np.nan)
    v_hist = np.full(n, np.nan)
    dev = np.full(n, np.nan)
    if len(hist.temporal) == 0 or len(hist.stereo) == 0 or n == 0:
        return prev_right, d_hist, v_hist, dev
    partner = _index_map(hist.stereo, len(hist.kp_left))
    a_prev, a_cur = hist.temporal.idx_a, hist.temporal.idx_b
    b_prev = partner[a_prev]
    ok = b_prev >= 0
    a_prev, a_cur, b_prev = a_prev[ok], a_cur[ok], b_prev[ok]
    if len(a_cur) == 0:
        return prev_right, d_hist, v_hist, dev
    d_prev = hist.kp_left[a_prev, 0] - hist.kp_right[b_prev, 0]
    v_prev = hist.kp_right[b_prev, 1] - hist.kp_left[a_prev, 1]
    dt = np.asarray(disparity, np.float64).reshape(-1)[a_cur]
    change = dt - d_prev
    fin = np.isfinite(change)
    if fin.sum() >= 3:
        ch = field_at(kl[a_cur[fin]], change[fin, None], kl[a_cur], k)[:, 0]
    else:
        ch = np.zeros(len(a_cur))
    prev_right[a_cur] = b_prev
    d_hist[a_cur] = d_prev + ch
    v_hist[a_cur] = v_prev
    dev[a_cur] = dt - d_hist[a_cur]
    return prev_right, d_hist, v_hist, dev


def history_cue_candidates(kl: np.ndarray, kr: np.ndarray, width: int, gates: GateConfig | None,
                           cfg: SemanticConfig, disparity: np.ndarray, cues: StereoCues, hist: StereoHistory | None,
                           sums: tuple[np.ndarray, np.ndarray] | None = None
                           ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Stereo candidates ``(ia, ib)`` of frame t and their cue rows (columns :data:`CUE_NAMES` +
    :data:`HISTORY_CUE_NAMES`): what :func:`history_prior_assign` scores and what
    ``benchmarks/fit_assoc_history.py`` labels with ground truth (one code path).

    Candidates: those of :func:`stereo_cue_candidates` (within ``mlp_gate_sigma`` of the dense
    disparity prior) plus, for left keypoints with a history, the gated right keypoints within
    ``history_gate_sigma`` (units of ``prior_sigma_px``) of the position predicted from t-1,
    ``(u - d_hist, v + v_hist)`` (:func:`history_prior`): a seed whose dense disparity is wrong (the
    occluder's, at a depth edge) keeps its disparity of t-1. Cues of a candidate, besides the 17 of
    :func:`cue_features`:

    * ``has_history``: 1 when its left keypoint is tracked to a stereo pair of t-1, else 0 (the
      other history cues are then at their caps);
    * ``hist_u_res`` / ``hist_v_res``: |disparity - d_hist| and |row offset - v_hist| (full-res px
      / 10, capped at 4);
    * ``hist_ncc_right`` / ``hist_ncc_right_large``: 1 - grey NCC (11 and 19 px at 1434 px) of the
      candidate's right patch at t and the right patch of the t-1 partner (same camera, one frame
      apart: the "loop-closed" check that the candidate is the t-1 partner seen again);
    * ``hist_disp_dev``: |dense disparity - d_hist| of the left keypoint (full-res px / 10, capped at
      4): how much the dense prior itself disagrees with the history (a depth edge)."""
    empty = _no_candidates(len(CUE_NAMES) + len(HISTORY_CUE_NAMES))
    c = _dense_prior_candidates(kl, kr, width, gates, cfg, disparity, sums)
    if c is None:
        return empty
    kl, kr, s, gate, ia, ib = c.kl, c.kr, c.s, c.gate, c.ia, c.ib
    n = len(kl)
    if hist is not None:
        prev_right, d_hist, v_hist, dev = history_prior(kl, hist, disparity, width, cfg.field_k)
    else:
        prev_right, d_hist, v_hist, dev = (np.full(n, -1, np.int64), np.full(n, np.nan), np.full(n, np.nan),
                                           np.full(n, np.nan))
    has = prev_right >= 0
    if has.any():
        hl = np.flatnonzero(has)
        hsig = np.broadcast_to(np.asarray(cfg.prior_sigma_px, np.float64) / s, (len(hl), 2))
        ja, jb, _ = _prior_candidates(kl[hl], kr, lambda a, b: gate(hl[a], b), np.c_[-d_hist[hl], v_hist[hl]], hsig,
                                      cfg.history_gate_sigma)
        m = len(kr)
        key = np.unique(np.r_[ia * m + ib, hl[ja] * m + jb])
        ia, ib = key // m, key % m
    if len(ia) == 0:
        return empty
    x = c.cue_rows(ia, ib, cues, cfg, width)
    h = has[ia]
    hu = np.full(len(ia), 4.0)
    hv = np.full(len(ia), 4.0)
    hn = np.full(len(ia), 1.0)
    hnl = np.full(len(ia), 1.0)
    hd = np.full(len(ia), 4.0)
    if h.any() and hist is not None:
        a, b = ia[h], ib[h]
        hu[h] = np.minimum(np.abs(kl[a, 0] - kr[b, 0] - d_hist[a]) * s, 40.0) / 10.0
        hv[h] = np.minimum(np.abs(kr[b, 1] - kl[a, 1] - v_hist[a]) * s, 40.0) / 10.0
        _, mid, large = cue_patch_sizes(width, cfg.patch_px)
        from seedmap.associate.disparity import patch_ncc

        hn[h] = 1.0 - patch_ncc(hist.right.patches[mid], cues.right.patches[mid], prev_right[a], b)
        hnl[h] = 1.0 - patch_ncc(hist.right.patches[large], cues.right.patches[large], prev_right[a], b)
        hd[h] = np.minimum(np.nan_to_num(np.abs(dev[a]) * s, nan=40.0), 40.0) / 10.0
    return ia, ib, np.c_[x, h.astype(np.float64), hu, hv, hn, hnl, hd]


def history_prior_assign(kl: np.ndarray, kr: np.ndarray, width: int, gates: GateConfig | None, cfg: SemanticConfig,
                         disparity: np.ndarray, cues: StereoCues, hist: StereoHistory | None,
                         sums: tuple[np.ndarray, np.ndarray] | None = None) -> Matches:
    """Stereo association of ``stereo_history=True`` (session 9): the candidates and cues of
    :func:`history_cue_candidates`, the log-odds of ``history_score_model`` (a network of the
    ``mlp`` score's shape, ``kind="stereo_history"``), one-to-one assignment and ambiguity test as
    :func:`assign_logits` with ``history_min_logit`` / ``history_margin``. Without a history (first
    frame of a sequence) every candidate has ``has_history`` 0; the same network scores it."""
    kl = np.asarray(kl, np.float64).reshape(-1, 2)
    kr = np.asarray(kr, np.float64).reshape(-1, 2)
    ia, ib, x = history_cue_candidates(kl, kr, width, gates, cfg, disparity, cues, hist, sums)
    if len(ia) == 0:
        return Matches()
    t = score_model(cfg.history_score_model, "stereo_history").logits(x)
    return assign_logits(ia, ib, t, len(kl), len(kr), cfg.history_min_logit, cfg.history_margin)


def _disparity_prior(kl: np.ndarray, disparity: np.ndarray, cfg: SemanticConfig,
                     s: float) -> tuple[np.ndarray, np.ndarray] | None:
    """``(pred, sig)`` (N, 2 each; image px) of a per-keypoint dense disparity (NaN = unknown):
    the displacement ``(-D, 0)`` with spread ``prior_sigma_px``; keypoints without a disparity take
    the median of their ``field_k`` nearest known ones' with the wider ``field_stereo_sigma_px``.
    None with fewer than 3 known disparities."""
    d = np.asarray(disparity, np.float64).reshape(-1)
    known = np.isfinite(d)
    if known.sum() < 3:
        return None
    if not known.all():
        d = d.copy()
        d[~known] = field_at(kl[known], d[known, None], kl[~known], cfg.field_k)[:, 0]
    sig = np.where(known[:, None], np.asarray(cfg.prior_sigma_px, np.float64) / s,
                   np.asarray(cfg.field_stereo_sigma_px, np.float64) / s)
    return np.c_[-d, np.zeros(len(d))], sig


def _field_candidates(ka: np.ndarray, kb: np.ndarray, pred: np.ndarray, sig: np.ndarray, gate,
                      gate_sigma: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Gated candidate pairs within ``gate_sigma`` normalised residual of the predicted field and
    their residuals ``|(kb - ka - pred) / sig|``."""
    ia, ib = box_pairs(ka + pred, kb, gate_sigma * sig)
    ok = gate(ia, ib)
    ia, ib = ia[ok], ib[ok]
    r = (kb[ib] - ka[ia] - pred[ia]) / sig
    res = np.hypot(r[:, 0], r[:, 1])
    ok = res <= gate_sigma
    return ia[ok], ib[ok], res[ok]


def _mutual_best(ia: np.ndarray, ib: np.ndarray, c: np.ndarray, n: int, m: int) -> Matches:
    """Pairs that are each other's lowest-``c`` candidate."""
    if len(ia) == 0:
        return Matches()
    a1, b1 = _best_per_row(ia, ib, c)
    b2, a2 = _best_per_row(ib, ia, c)
    best_a = np.full(m, -1)
    best_a[b2] = a2
    mutual = best_a[b1] == a1
    return Matches(a1[mutual], b1[mutual], np.zeros(int(mutual.sum())))


def _ratio_test(out: Matches, ia: np.ndarray, ib: np.ndarray, resid: np.ndarray, n: int, m: int,
                ratio: float) -> Matches:
    """Ambiguity test on the geometric residual: a kept pair must be clearly closer to the local
    field (``resid`` of every candidate ``(ia, ib)``) than any competitor sharing one of its
    keypoints (``resid_pair < ratio * resid_competitor``)."""
    if len(out) == 0 or ratio >= 1.0:
        return out
    pos = candidate_positions(ia, ib, m, out.idx_a, out.idx_b)
    alt = second_best(ia, ib, resid, out, n, m)
    keep = resid[pos] < ratio * alt
    return Matches(out.idx_a[keep], out.idx_b[keep], out.cost[keep])


def _inside(u: np.ndarray, width: int, border: float) -> np.ndarray:
    return (u >= border) & (u <= width - 1 - border)


# ----------------------------------------------------------------------------------------------
# stereo and temporal matching on keypoint sets
# ----------------------------------------------------------------------------------------------


def match_stereo_keypoints(
    kp_left: np.ndarray, kp_right: np.ndarray, width: int, gates: GateConfig | None = None,
    cfg: SemanticConfig | None = None, sums: tuple[np.ndarray, np.ndarray] | None = None,
    init_field: np.ndarray | None = None, iters: int | None = None, disparity: np.ndarray | None = None,
    disparity_right: np.ndarray | None = None, appearance: tuple[np.ndarray, np.ndarray] | None = None,
    cues: StereoCues | None = None, history: StereoHistory | None = None,
) -> Matches:
    """Left<->right association of one rectified stereo pair (pixels of an image ``width`` wide).

    ``sums``: precomputed :func:`neighbour_sums` of both images in full-resolution units (cache).
    ``init_field``/``iters``: ``refine="field"`` only, see :func:`field_assign`.
    ``disparity`` (N,): dense-stereo disparity of every left keypoint (image px, NaN = unknown;
    :mod:`seedmap.associate.disparity`): when given, the pairs are assigned around
    ``(u - D, v)`` (:func:`prior_assign`, spread ``prior_sigma_px``) instead of the ``refine``
    method; keypoints without a disparity take the median of their ``field_k`` nearest keypoints'
    with the wider ``field_stereo_sigma_px``. ``disparity_right`` (M,): the right image's dense
    disparity at every right keypoint (NaN = unknown): with ``sgbm_lr_tol_px > 0`` a pair is
    dropped when ``u_right + D_right`` is farther than that from ``u_left`` (left-right check).
    ``appearance``: patch descriptors (left, right) of every keypoint
    (:func:`seedmap.associate.disparity.patch_descriptors`); with ``prior_score="learned"`` and a
    ``disparity`` the pairs are scored by :func:`scored_prior_assign` instead of
    :func:`prior_assign`. ``cues``: with ``prior_score="mlp"`` and a ``disparity`` the pairs are
    scored by :func:`mlp_prior_assign` (the left-right, deviation and debias options do not apply), or
    with ``stereo_history`` by :func:`history_prior_assign` with ``history`` (None: no previous frame)."""
    cfg, g, kl, kr, s = _pair_inputs(kp_left, kp_right, width, gates, cfg)
    if len(kl) == 0 or len(kr) == 0:
        return Matches()
    fl, fr = kl * s, kr * s
    sa, sb = _full_res_sums(kl, kr, s, cfg, sums)
    if disparity is not None and cfg.prior_score == "mlp" and cues is not None:
        if np.isfinite(np.asarray(disparity, np.float64)).sum() >= 3:
            if cfg.stereo_history:
                return history_prior_assign(kl, kr, width, gates, cfg, disparity, cues, history, (sa, sb))
            return mlp_prior_assign(kl, kr, width, gates, cfg, disparity, cues, (sa, sb))
    if disparity is not None:
        prior = _disparity_prior(kl, disparity, cfg, s)
        if prior is not None:
            pred, sig = prior
            if cfg.prior_score == "learned" and appearance is not None:
                m = scored_prior_assign(kl, kr, sa, sb, _stereo_gate_fn(kl, kr, g, width), pred, sig, appearance[0],
                                        appearance[1], cfg, s)
            else:
                m = prior_assign(kl, kr, fl, fr, sa, sb, _stereo_gate_fn(kl, kr, g, width), pred, sig, cfg)
            if cfg.prior_debias and len(m) >= 10 and not (cfg.prior_score == "learned" and appearance is not None):
                pred[:, 0] += np.median(kr[m.idx_b, 0] - kl[m.idx_a, 0] - pred[m.idx_a, 0])
                m = prior_assign(kl, kr, fl, fr, sa, sb, _stereo_gate_fn(kl, kr, g, width), pred, sig, cfg)
            if disparity_right is not None and cfg.sgbm_lr_tol_px > 0 and len(m):
                dr = np.asarray(disparity_right, np.float64).reshape(-1)[m.idx_b]
                bad = np.abs(kr[m.idx_b, 0] + dr - kl[m.idx_a, 0]) > cfg.sgbm_lr_tol_px / s  # NaN: not tested
                m = Matches(m.idx_a[~bad], m.idx_b[~bad], m.cost[~bad])
            if cfg.prior_max_dev_px > 0 and len(m) > cfg.field_k:
                disp = kl[m.idx_a, 0] - kr[m.idx_b, 0]
                dev = disp - loo_local_median(kl[m.idx_a], disp[:, None], cfg.field_k)[:, 0]
                keep = np.abs(dev) <= cfg.prior_max_dev_px / s
                m = Matches(m.idx_a[keep], m.idx_b[keep], m.cost[keep])
            return m
    if cfg.refine == "field":
        gate = _stereo_gate_fn(kl, kr, g, width)
        band = cfg.field_stereo_band_px / s
        lo = np.array([-cfg.field_max_disparity_px / s, -band])
        hi = np.array([-g.stereo_min_disparity_px, band])
        extent = (float(width), float(max(kl[:, 1].max(), kr[:, 1].max())) + 1.0)
        return field_assign(kl, kr, fl, fr, sa, sb, gate, lo, hi, np.asarray(cfg.field_stereo_sigma_px) / s,
                            cfg, s, extent, fixed_v=0.0, init=init_field, iters=iters)
    ia, ib = candidate_pairs(kl, kr, g.stereo_max_dy_px)
    ok = (kl[ia, 0] - kr[ib, 0]) >= g.stereo_min_disparity_px
    ok &= _inside(kl[ia, 0], width, g.stereo_border_px) & _inside(kr[ib, 0], width, g.stereo_border_px)
    ia, ib = ia[ok], ib[ok]
    cost = pair_cost(fl, fr, sa, sb, cfg, ia, ib)
    if cfg.refine == "consensus":
        return consensus_assign(kl, kr, ia, ib, cost, cfg, s)
    return assign_sparse(len(kl), len(kr), ia, ib, cost, cfg.max_cost)


def _temporal_search(ka: np.ndarray, kb: np.ndarray, width: int, g: GateConfig, cfg: SemanticConfig,
                     predicted_shift: float | None, predicted_shift_v: float | None):
    """``(gate, lo, hi, extent)`` of the temporal ``field`` matching of ``ka`` (previous left, image
    px) with ``kb`` (current left): the gate function of the horizontal-travel gates (``g`` already
    scaled), the displacement box searched by the coarse field (around the constant-velocity
    prediction when given, else the whole travel gate) and the image extent (u, v)."""
    s = full_res_scale(width)
    gate = _temporal_gate_fn(ka, kb, g, width)
    vband = min(g.temporal_max_dy_px, g.temporal_post_max_dy_px)
    if predicted_shift is not None:
        tol = cfg.prediction_tol_px / s
        pv = 0.0 if predicted_shift_v is None else float(predicted_shift_v)
        lo = np.array([predicted_shift - tol, pv - vband])
        hi = np.array([predicted_shift + tol, pv + vband])
    else:
        far = g.travel_sign * cfg.field_max_shift_px / s
        near = g.travel_sign * g.temporal_min_shift_px
        lo = np.array([min(far, near), -vband])
        hi = np.array([max(far, near), vband])
    extent = (float(width), float(max(ka[:, 1].max(), kb[:, 1].max())) + 1.0)
    return gate, lo, hi, extent


def match_temporal_keypoints(
    kp_prev: np.ndarray, kp_cur: np.ndarray, width: int, gates: GateConfig | None = None,
    cfg: SemanticConfig | None = None, predicted_shift: float | None = None,
    predicted_shift_v: float | None = None, sums: tuple[np.ndarray, np.ndarray] | None = None,
    init_field: np.ndarray | None = None, iters: int | None = None,
) -> Matches:
    """Previous-left <-> current-left association under the horizontal-travel gates.

    ``predicted_shift`` (pixels of this image, u_cur - u_prev) enables the constant-velocity gate
    and the ``overlap`` neighbour option when ``cfg`` asks for them; ``None`` = no prediction.
    ``predicted_shift_v`` (v_cur - v_prev) centres the vertical search of ``refine="field"``.
    ``sums``: precomputed :func:`neighbour_sums` (full-resolution units) of both keypoint sets,
    used only with ``neighbours="all"``. ``init_field``/``iters``: ``refine="field"`` only, see
    :func:`field_assign`.
    """
    cfg, g, ka, kb, s = _pair_inputs(kp_prev, kp_cur, width, gates, cfg)
    if len(ka) == 0 or len(kb) == 0:
        return Matches()
    fa, fb = ka * s, kb * s
    va = vb = None
    if cfg.neighbours == "overlap" and predicted_shift is not None:
        # count only neighbours that are inside the view common to both frames
        va = _inside(ka[:, 0] + predicted_shift, width, 0.0)
        vb = _inside(kb[:, 0] - predicted_shift, width, 0.0)
    if sums is not None and va is None:
        sa, sb = sums
    else:
        sa = neighbour_sums(fa, cfg.delta_px, cfg.eps_px, va, chunk=cfg.chunk)
        sb = neighbour_sums(fb, cfg.delta_px, cfg.eps_px, vb, chunk=cfg.chunk)
    if cfg.refine == "field":
        gate, lo, hi, extent = _temporal_search(ka, kb, width, g, cfg, predicted_shift, predicted_shift_v)
        return field_assign(ka, kb, fa, fb, sa, sb, gate, lo, hi, np.asarray(cfg.field_temporal_sigma_px) / s,
                            cfg, s, extent, init=init_field, iters=iters)
    ia, ib = candidate_pairs(ka, kb, g.temporal_max_dy_px)
    du = kb[ib, 0] - ka[ia, 0]
    ok = g.travel_sign * du >= g.temporal_min_shift_px
    if cfg.temporal_prediction and predicted_shift is not None:
        ok &= np.abs(du - predicted_shift) <= cfg.prediction_tol_px / s
    ok &= _inside(ka[ia, 0], width, g.temporal_border_px) & _inside(kb[ib, 0], width, g.temporal_border_px)
    ia, ib = ia[ok], ib[ok]
    cost = pair_cost(fa, fb, sa, sb, cfg, ia, ib)
    if cfg.refine == "consensus":
        m = consensus_assign(ka, kb, ia, ib, cost, cfg, s)
    else:
        m = assign_sparse(len(ka), len(kb), ia, ib, cost, cfg.max_cost)
    # post-filter on the vertical offset (facts.md: 60 px at full resolution)
    keep = np.abs(kb[m.idx_b, 1] - ka[m.idx_a, 1]) <= g.temporal_post_max_dy_px
    return Matches(m.idx_a[keep], m.idx_b[keep], m.cost[keep])


# ----------------------------------------------------------------------------------------------
# stereo-temporal loop: carry stereo matches through time, confirm temporal matches by stereo
# ----------------------------------------------------------------------------------------------


def _stereo_gate_fn(kl: np.ndarray, kr: np.ndarray, g: GateConfig, width: int):
    """``gate(ia, ib) -> bool``: the stereo gates (|Δv|, minimum disparity, border margins) of
    pairs ``(kl[ia], kr[ib])``; ``g`` already scaled to ``width``."""
    def gate(ia: np.ndarray, ib: np.ndarray) -> np.ndarray:
        return (((kl[ia, 0] - kr[ib, 0]) >= g.stereo_min_disparity_px)
                & (np.abs(kl[ia, 1] - kr[ib, 1]) <= g.stereo_max_dy_px)
                & _inside(kl[ia, 0], width, g.stereo_border_px) & _inside(kr[ib, 0], width, g.stereo_border_px))
    return gate


def _temporal_gate_fn(ka: np.ndarray, kb: np.ndarray, g: GateConfig, width: int):
    """``gate(ia, ib) -> bool``: the temporal gates of pairs ``(ka[ia], kb[ib])`` (``g`` scaled)."""
    def gate(ia: np.ndarray, ib: np.ndarray) -> np.ndarray:
        return ((g.travel_sign * (kb[ib, 0] - ka[ia, 0]) >= g.temporal_min_shift_px)
                & (np.abs(kb[ib, 1] - ka[ia, 1]) <= min(g.temporal_max_dy_px, g.temporal_post_max_dy_px))
                & _inside(ka[ia, 0], width, g.temporal_border_px) & _inside(kb[ib, 0], width, g.temporal_border_px))
    return gate


def _unique_hits(q: np.ndarray, pts: np.ndarray, free: np.ndarray, half: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Queries ``q`` with exactly one free point of ``pts`` inside the box ``±half`` that no other
    query hits: (query index, point index)."""
    idx = np.flatnonzero(free)
    if len(q) == 0 or len(idx) == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    i, j = box_pairs(q, pts[idx], half)
    once_i = np.bincount(i, minlength=len(q))[i] == 1
    once_j = np.bincount(j, minlength=len(idx))[j] == 1
    sel = once_i & once_j
    return i[sel], idx[j[sel]]


def _recover_one_side(pl: np.ndarray, pr: np.ndarray, kl: np.ndarray, kr: np.ndarray, prev_stereo: Matches,
                      ml: np.ndarray, mr: np.ndarray, tl: Matches, tr: Matches, e_med: np.ndarray, tol: np.ndarray,
                      stereo_gate, temporal_gate) -> tuple[Matches, Matches]:
    """Stereo pairs of t-1 whose left *or* right keypoint was lost by the temporal matching.

    The lost keypoint is predicted from the other side's position at t and the pair's
    (disparity, row offset) at t-1 plus the median change ``e_med``; a unique untaken keypoint
    within ``tol`` (image px, per axis) is taken. Returns the recovered stereo pairs of t and the
    left temporal matches ``tl`` extended by the recovered left keypoints."""
    ap, bp = prev_stereo.idx_a, prev_stereo.idx_b
    lt, rt = ml[ap], mr[bp]
    disp = pl[ap] - pr[bp]
    taken_l = np.zeros(len(kl), bool)
    taken_l[tl.idx_b] = True
    taken_r = np.zeros(len(kr), bool)
    taken_r[tr.idx_b] = True
    # right lost: r ~ l - (disparity at t-1 + change)
    s1 = np.flatnonzero((lt >= 0) & (rt < 0))
    qi, rj = _unique_hits(kl[lt[s1]] - disp[s1] - e_med, kr, ~taken_r, tol)
    a1, b1 = lt[s1[qi]], rj
    ok1 = stereo_gate(a1, b1)
    a1, b1 = a1[ok1], b1[ok1]
    # left lost: l ~ r + (disparity at t-1 + change); the pair (a', l) is also a temporal match
    s2 = np.flatnonzero((lt < 0) & (rt >= 0))
    qi, lj = _unique_hits(kr[rt[s2]] + disp[s2] + e_med, kl, ~taken_l, tol)
    a2, b2, ta = lj, rt[s2[qi]], ap[s2[qi]]
    ok2 = stereo_gate(a2, b2) & temporal_gate(ta, a2)
    a2, b2, ta = a2[ok2], b2[ok2], ta[ok2]
    rec = Matches(np.r_[a1, a2], np.r_[b1, b2], np.zeros(len(a1) + len(a2)))
    tl2 = Matches(np.r_[tl.idx_a, ta], np.r_[tl.idx_b, a2], np.r_[tl.cost, np.zeros(len(ta))])
    return rec, tl2


def _index_map(m: Matches, n: int) -> np.ndarray:
    """``(n,)`` partner in B of every A index of the one-to-one matching ``m`` (-1: none)."""
    out = np.full(n, -1, np.int64)
    out[m.idx_a] = m.idx_b
    return out


def field_at(pos: np.ndarray, disp: np.ndarray, query: np.ndarray, k: int) -> np.ndarray:
    """Median displacement ``disp`` (P, 2) of the ``k`` points ``pos`` (P, 2) nearest to each query
    point (N, 2): a smooth field known at scattered points, evaluated elsewhere."""
    from scipy.spatial import cKDTree

    kk = min(k, len(pos))
    _, nn = cKDTree(pos).query(query, kk)
    return np.median(disp[np.asarray(nn).reshape(len(query), kk)], axis=1)


def _median_rows(v: np.ndarray) -> np.ndarray:
    """``np.median(v, axis=-1)`` of a ``(..., k)`` array, bit for bit, for finite values: one
    ``np.partition`` at the middle (two middles for even ``k``, averaged as ``np.median`` does)
    without its axis moves and NaN bookkeeping (the median of the field's neighbours is the
    field association's most frequent operation)."""
    k = v.shape[-1]
    if np.isnan(v).any():
        return np.median(v, axis=-1)
    h = k // 2
    if k % 2:
        return np.partition(v, h, axis=-1)[..., h]
    p = np.partition(v, (h - 1, h), axis=-1)
    return (p[..., h - 1] + p[..., h]) / 2.0


def loo_local_median(pos: np.ndarray, val: np.ndarray, k: int, tree=None) -> np.ndarray:
    """Median of ``val`` over the ``k`` nearest *other* points of every point ``pos`` (N, 2).

    ``val`` (N, D). Leave-one-out, so an outlier never hides itself in its own median; with fewer
    than 2 points the values themselves are returned (no neighbours to compare with). ``tree``: a
    ``cKDTree`` of ``pos`` when the caller has one (built here otherwise)."""
    from scipy.spatial import cKDTree

    n = len(pos)
    val = np.asarray(val, np.float64)
    if n < 2:
        return val.copy()
    kk = min(k + 1, n)
    _, nn = (tree if tree is not None else cKDTree(pos)).query(pos, kk)
    nn = np.asarray(nn).reshape(n, kk)
    is_self = nn == np.arange(n)[:, None]
    if is_self[:, 0].all():  # the usual case: every point is its own nearest neighbour
        others = nn[:, 1:]
    else:
        # drop the own point (first column unless positions repeat), else the farthest neighbour
        drop = np.where(is_self.any(1), is_self.argmax(1), kk - 1)
        keep = np.ones_like(nn, bool)
        keep[np.arange(n), drop] = False
        others = nn[keep].reshape(n, kk - 1)
    # (D, N, k): the median runs over the contiguous last axis
    return _median_rows(val.reshape(n, -1).T[:, others]).T.reshape(val.shape)


@dataclass
class LoopStep:
    """One frame of the stereo-temporal loop (:func:`loop_associate`).

    ``stereo`` = ``carried`` ∪ ``new`` (left<->right of the current frame); ``temporal`` the
    loop-checked previous-left <-> current-left matches, ``temporal_right`` the right-image ones;
    ``n_contradicted`` temporal pairs dropped by the loop check; ``n_carry_rejected`` carried
    candidates that failed the gates or the loop residual."""

    stereo: Matches
    temporal: Matches
    temporal_right: Matches
    carried: Matches
    new: Matches
    n_carry_rejected: int
    n_contradicted: int
    track: np.ndarray
    cpu_ms: dict[str, float]
    candidates: Matches | None = None


def loop_associate(
    prev_left: np.ndarray, prev_right: np.ndarray, prev_stereo: Matches, kl: np.ndarray, kr: np.ndarray,
    width: int, gates: GateConfig | None = None, cfg: SemanticConfig | None = None,
    predicted_shift: float | None = None, predicted_shift_v: float | None = None,
    sums_prev: tuple[np.ndarray, np.ndarray] | None = None, sums_cur: tuple[np.ndarray, np.ndarray] | None = None,
    prev_track: np.ndarray | None = None, prev_flow: tuple[np.ndarray, np.ndarray] | None = None,
) -> LoopStep:
    """Stereo and temporal association of frame t given frame t-1 and its stereo matches.

    ``prev_left``/``prev_right`` keypoints of t-1, ``prev_stereo`` its stereo candidates (the pairs
    that passed the checks, also those not yet tested and therefore not output),
    ``kl``/``kr`` keypoints of t (image px); ``sums_*`` neighbour sums (full-res) of (left, right);
    ``prev_track`` (N_prev, K, 2) the image positions of every left keypoint of t-1 in frames
    t-2 ... t-1-K along its temporal track (NaN where not tracked; None = no history);
    ``prev_flow`` (positions at t-1, shifts from t-2) of the previous temporal matches: with it (and
    for the right image and the new stereo pairs always, from the left matches and the carried
    pairs) the ``field`` machinery starts from that field instead of a coarse histogram and refines
    it ``carry_field_iters`` times.
    Steps (see the module docstring): temporal left and right (``refine="field"`` machinery,
    independently), stereo carried through them and kept when it passes the stereo gates and the
    loop residual, ``field`` stereo of the current pair for the keypoints not carried, the parallax
    test of every stereo pair whose left keypoint has a track, and the loop check of the temporal
    matches.
    """
    cfg, g, kl, kr, s = _pair_inputs(kl, kr, width, gates, cfg)
    pl = np.asarray(prev_left, np.float64).reshape(-1, 2)
    pr = np.asarray(prev_right, np.float64).reshape(-1, 2)
    K = max(1, cfg.parallax_frames)
    sums_cur = _full_res_sums(kl, kr, s, cfg, sums_cur)
    sums_prev = _full_res_sums(pl, pr, s, cfg, sums_prev)
    if prev_track is None:
        prev_track = np.full((len(pl), K, 2), np.nan)
    # 1. temporal matching of both images, independently (so the loop is a real check)
    c0 = time.process_time()
    it = cfg.carry_field_iters
    init_l = None
    if cfg.carry_init_fields and prev_flow is not None and len(prev_flow[0]) >= cfg.field_k and len(pl):
        init_l = field_at(prev_flow[0], prev_flow[1], pl, cfg.field_k)  # constant velocity per place
    tl = match_temporal_keypoints(pl, kl, width, gates, cfg, predicted_shift, predicted_shift_v,
                                  sums=(sums_prev[0], sums_cur[0]), init_field=init_l,
                                  iters=None if init_l is None else it)
    pred_r, pred_rv = predicted_shift, predicted_shift_v
    init_r = None
    if len(tl) >= max(5, cfg.field_k) and len(pr):
        d = kl[tl.idx_b] - pl[tl.idx_a]
        pred_r, pred_rv = float(np.median(d[:, 0])), float(np.median(d[:, 1]))
    if cfg.carry_init_fields and len(tl) >= max(5, cfg.field_k) and len(pr):
        # the right image moves like the left one: the left field at each right keypoint's left
        # position (its stereo partner at t-1, else the median disparity away)
        where = pr + [float(np.median(pl[prev_stereo.idx_a, 0] - pr[prev_stereo.idx_b, 0])) if len(prev_stereo)
                      else 0.0, 0.0]
        where[prev_stereo.idx_b] = pl[prev_stereo.idx_a]
        init_r = field_at(pl[tl.idx_a], d, where, cfg.field_k)
    c1 = time.process_time()
    tr = match_temporal_keypoints(pr, kr, width, gates, cfg, pred_r, pred_rv, sums=(sums_prev[1], sums_cur[1]),
                                  init_field=init_r, iters=None if init_r is None else it)
    c2 = time.process_time()
    cpu = {"temporal_left_cpu": (c1 - c0) * 1e3, "temporal_right_cpu": (c2 - c1) * 1e3}
    track = np.full((len(kl), K, 2), np.nan)
    if len(kl) == 0 or len(kr) == 0:
        return LoopStep(Matches(), tl, tr, Matches(), Matches(), 0, 0, track, cpu, Matches())
    # 2. carry: (a', b') at t-1 -> (T_L(a'), T_R(b')) at t
    ml, mr = _index_map(tl, len(pl)), _index_map(tr, len(pr))
    a_prev, b_prev = prev_stereo.idx_a, prev_stereo.idx_b
    cl, cr = ml[a_prev], mr[b_prev]
    have = (cl >= 0) & (cr >= 0)
    a_prev, b_prev, cl, cr = a_prev[have], b_prev[have], cl[have], cr[have]
    gate = _stereo_gate_fn(kl, kr, g, width)
    ok = gate(cl, cr)
    # loop residual: change of (disparity, row offset) of the pair, minus its neighbours' change
    e = (kl[cl] - kr[cr]) - (pl[a_prev] - pr[b_prev])
    tol = np.asarray(cfg.carry_tol_px, np.float64) / s
    loop_ok = np.zeros(len(cl), bool)
    if ok.any():
        idx = np.flatnonzero(ok)
        med = loo_local_median(kl[cl[idx]], e[idx], cfg.carry_k)
        loop_ok[idx] = (np.abs(e[idx] - med) / tol <= 1.0).all(1)
    keep = ok & loop_ok
    carried = Matches(cl[keep], cr[keep], np.zeros(int(keep.sum())))
    n_rej = int((~keep).sum())
    if cfg.carry_recover and len(carried) >= 3:
        # one side lost in time: predict it from the other side's displacement and the pair's
        # disparity at t-1; keep a unique keypoint inside the loop tolerance (the parallax test
        # below checks the result like every other pair)
        e_med = np.median(e[keep], axis=0)
        rec, tl = _recover_one_side(pl, pr, kl, kr, prev_stereo, ml, mr, tl, tr, e_med, tol, gate,
                                    _temporal_gate_fn(pl, kl, g, width))
        carried = Matches(np.r_[carried.idx_a, rec.idx_a], np.r_[carried.idx_b, rec.idx_b],
                          np.r_[carried.cost, rec.cost])
    # 3. stereo of the current pair for the rest
    used_l = np.zeros(len(kl), bool)
    used_l[carried.idx_a] = True
    used_r = np.zeros(len(kr), bool)
    used_r[carried.idx_b] = True
    # only the keypoints not carried (fewer points, fewer distractors), inside the carried field
    il, ir = np.flatnonzero(~used_l), np.flatnonzero(~used_r)
    init_s = None
    if cfg.carry_init_fields and len(carried) >= cfg.field_k and len(il):
        init_s = field_at(kl[carried.idx_a], kr[carried.idx_b] - kl[carried.idx_a], kl[il], cfg.field_k)
    sub = match_stereo_keypoints(kl[il], kr[ir], width, gates, cfg, sums=(sums_cur[0][il], sums_cur[1][ir]),
                                 init_field=init_s, iters=None if init_s is None else it)
    new = Matches(il[sub.idx_a], ir[sub.idx_b], sub.cost)
    # 4. loop check of the left temporal matches
    temporal, n_con = tl, 0
    stereo0 = Matches(np.r_[carried.idx_a, new.idx_a], np.r_[carried.idx_b, new.idx_b], np.r_[carried.cost, new.cost])
    if cfg.loop_temporal and len(tl):
        s_prev = _index_map(prev_stereo, len(pl))
        s_cur = _index_map(stereo0, len(kl))
        a, b = tl.idx_a, tl.idx_b
        ap = s_prev[a]
        pr_b = np.where(ap >= 0, mr[np.maximum(ap, 0)], -1)  # right partner predicted through T_R
        bp = s_cur[b]
        contra = (pr_b >= 0) & (bp >= 0) & (pr_b != bp)
        failed = np.zeros(len(kl), bool)  # a carried candidate through this pair failed the loop residual
        failed[cl[ok & ~loop_ok]] = True
        contra |= (pr_b >= 0) & (bp < 0) & failed[b]
        n_con = int(contra.sum())
        temporal = Matches(a[~contra], b[~contra], tl.cost[~contra])
        if cfg.temporal_parallax_tol_px > 0:
            bad = _temporal_outliers(pl, pr, kl, prev_stereo, temporal, cfg.temporal_parallax_tol_px / s, cfg.carry_k)
            n_con += int(bad.sum())
            temporal = Matches(temporal.idx_a[~bad], temporal.idx_b[~bad], temporal.cost[~bad])
    # track positions of the current left keypoints in frames t-1 ... t-K
    track[temporal.idx_b, 0] = pl[temporal.idx_a]
    if K > 1:
        track[temporal.idx_b, 1:] = prev_track[temporal.idx_a, : K - 1]
    # 5. parallax test: along a track of k frames the image shift of a static seed is proportional
    # to its disparity (shift = alpha_k * disparity + smooth rotation terms), so a wrong stereo
    # partner (a neighbour a few px off in u) leaves a residual that grows with k
    stereo = candidates = stereo0
    if cfg.parallax_tol_px > 0 and len(stereo0):
        bad, tested = _parallax_outliers(kl, kr, stereo0, track, cfg.parallax_min_frames,
                                         cfg.parallax_tol_px / s, cfg.carry_k)
        candidates = Matches(stereo0.idx_a[~bad], stereo0.idx_b[~bad], stereo0.cost[~bad])
        out = ~bad & (tested if cfg.stereo_output == "verified" else True)
        stereo = Matches(stereo0.idx_a[out], stereo0.idx_b[out], stereo0.cost[out])
        nc = len(carried)
        carried = Matches(carried.idx_a[out[:nc]], carried.idx_b[out[:nc]], carried.cost[out[:nc]])
        new = Matches(new.idx_a[out[nc:]], new.idx_b[out[nc:]], new.cost[out[nc:]])
    if cfg.stereo_output == "frame":  # the loop only checks time; triangulation uses per-frame stereo
        stereo = match_stereo_keypoints(kl, kr, width, gates, cfg, sums=sums_cur)
    cpu["stereo_loop_cpu"] = (time.process_time() - c2) * 1e3
    return LoopStep(stereo, temporal, tr, carried, new, n_rej, n_con, track, cpu, candidates)


def _temporal_outliers(pl: np.ndarray, pr: np.ndarray, kl: np.ndarray, prev_stereo: Matches, tm: Matches,
                       tol: float, k: int) -> np.ndarray:
    """``(len(tm),)`` bool: temporal pairs whose shift disagrees with the disparity of their stereo
    pair at t-1 (the u shift of a static seed is ``alpha * disparity + beta``; the v shift is smooth),
    after removing the leave-one-out local median residual of the ``k`` nearest such pairs. Pairs
    without a stereo partner at t-1 are not tested."""
    bad = np.zeros(len(tm), bool)
    sp = _index_map(prev_stereo, len(pl))[tm.idx_a]
    sel = np.flatnonzero(sp >= 0)
    if len(sel) < max(8, k):
        return bad
    a, b = tm.idx_a[sel], tm.idx_b[sel]
    x = pl[a, 0] - pr[sp[sel], 0]
    du = kl[b] - pl[a]
    use = np.ones(len(sel), bool)
    for _ in range(3):
        A = np.c_[x[use], np.ones(int(use.sum()))]
        coef, *_ = np.linalg.lstsq(A, du[use, 0], rcond=None)
        r = du[:, 0] - (coef[0] * x + coef[1])
        mad = 1.4826 * np.median(np.abs(r[use] - np.median(r[use]))) + 1e-9
        use = np.abs(r) <= 3.0 * mad
    res = np.c_[r, du[:, 1]]
    res = res - loo_local_median(kl[b], res, k)
    bad[sel] = (np.abs(res) > tol).any(1)
    return bad


def _parallax_outliers(kl: np.ndarray, kr: np.ndarray, m: Matches, track: np.ndarray, min_frames: int,
                       tol: float, k: int) -> np.ndarray:
    """``(len(m),)`` bool: stereo pairs that fail the parallax test (see :func:`loop_associate`).

    Each pair is tested on its longest track (``track[l, j]`` = position ``j + 1`` frames back); per
    track length ``j + 1 >= min_frames`` the u shift is fitted as ``alpha * disparity + beta`` with
    two rounds of trimming, and the residual minus the leave-one-out local median of its ``k``
    nearest pairs' residuals must stay within ``tol`` (image px)."""
    bad = np.zeros(len(m), bool)
    tested = np.zeros(len(m), bool)
    valid = np.isfinite(track[m.idx_a, :, 0])  # (P, K)
    depth = np.where(valid.any(1), valid.shape[1] - 1 - np.argmax(valid[:, ::-1], axis=1), -1)
    disp = kl[m.idx_a, 0] - kr[m.idx_b, 0]
    for j in range(max(0, min_frames - 1), track.shape[1]):
        sel = np.flatnonzero(depth == j)
        if len(sel) < max(8, k):
            continue
        la = m.idx_a[sel]
        du = kl[la, 0] - track[la, j, 0]
        x = disp[sel]
        use = np.ones(len(sel), bool)
        for _ in range(3):
            A = np.c_[x[use], np.ones(int(use.sum()))]
            coef, *_ = np.linalg.lstsq(A, du[use], rcond=None)
            r = du - (coef[0] * x + coef[1])
            mad = 1.4826 * np.median(np.abs(r[use] - np.median(r[use]))) + 1e-9
            use = np.abs(r) <= 3.0 * mad
        r = r - loo_local_median(kl[la], r[:, None], k)[:, 0]
        bad[sel] = np.abs(r) > tol
        tested[sel] = True
    return bad, tested


# ----------------------------------------------------------------------------------------------
# the Matcher
# ----------------------------------------------------------------------------------------------


class SeedMatcher:
    """Seeds as semantic features: a detector gives keypoints, the semantic cost associates them.

    ``detector`` needs ``detect_stereo(frame: StereoFrame) -> StereoDetections`` (every seedmap
    detector has it); :meth:`features_from_detections` works without a detector.
    ``match_temporal`` remembers the median image shift of the last accepted temporal matches
    (used only by the optional constant-velocity prediction / overlap options).

    With ``cfg.stereo_carry`` the matcher is *sequential*: :meth:`features_from_detections` of a
    frame whose index follows the previous call's runs the stereo-temporal loop against that
    previous frame (:func:`loop_associate`): its stereo matches are the carried + new ones, and the
    loop-checked temporal matches are kept for the ``match_temporal(prev, cur)`` call that follows
    (any other pair of frames is matched directly). A frame with a smaller or equal index starts a
    new sequence (no history); :meth:`reset` forgets the history explicitly.
    """

    name = "seeds"

    def __init__(self, calib: StereoCalib, detector=None, cfg: SemanticConfig | None = None,
                 gates: GateConfig | None = None) -> None:
        self.calib = calib
        self.detector = detector
        self.cfg = cfg or SemanticConfig()
        self.gates = gates or GateConfig()
        self._last_shift: float | None = None
        self._last_shift_v: float | None = None
        #: neighbour sums of the last two frames' left keypoints (reused by match_temporal)
        self._sums: list[tuple[np.ndarray, np.ndarray]] = []
        #: stereo_carry: the last frame's features and right-image neighbour sums, and the last loop
        self._prev: FrameFeatures | None = None
        self._prev_sums_right: np.ndarray | None = None
        self._loop: tuple[FrameFeatures, FrameFeatures, LoopStep] | None = None
        self._prev_track: np.ndarray | None = None
        self._prev_candidates: Matches = Matches()
        self._prev_flow: tuple[np.ndarray, np.ndarray] | None = None
        #: stereo_prior="sgbm": (frame index, disparities of its stereo matches) for the next search range
        self._disp_known: tuple[int, np.ndarray] | None = None
        #: patch descriptors of the last two frames' left keypoints (temporal NCC verification)
        self._patches: list[tuple[np.ndarray, np.ndarray]] = []
        #: temporal_score="mlp": :class:`TemporalInputs` of the last two frames' left keypoints
        self._temporal_inputs: list[tuple[np.ndarray, TemporalInputs]] = []
        #: keep the last frame's stereo inputs (detections, dense disparity at the left keypoints,
        #: :class:`StereoCues` when the sgbm prior ran) in ``last_stereo_inputs``: the score fit
        #: (benchmarks/fit_assoc_score.py) labels exactly what the matcher would score
        self.keep_inputs = False
        self.last_stereo_inputs: tuple[StereoDetections, np.ndarray | None, StereoCues | None] | None = None
        #: stereo_history: the last frame's features and right-image cues, and the temporal matches
        #: (previous features, frame index, matches) computed before the stereo matching of a frame
        self._hist_prev: tuple[FrameFeatures, ImageCues] | None = None
        self._early_temporal: tuple[FrameFeatures, int, Matches] | None = None
        c = self.cfg
        if c.stereo_history and not (c.stereo_prior == "sgbm" and c.prior_score == "mlp" and c.temporal_score == "mlp"
                                     and c.refine == "field" and not c.stereo_carry):
            raise ConfigError("association.stereo_history needs stereo_prior=sgbm, prior_score=mlp, "
                              "temporal_score=mlp, refine=field and stereo_carry=false")

    def _cached_sums(self, kp: np.ndarray) -> np.ndarray:
        for arr, sums in self._sums:
            if arr is kp:
                return sums
        sums = neighbour_sums(kp * full_res_scale(self.calib.width), self.cfg.delta_px, self.cfg.eps_px)
        self._remember(kp, sums)
        return sums

    def _remember(self, kp: np.ndarray, sums: np.ndarray) -> None:
        self._sums = [*self._sums[-1:], (kp, sums)]

    def _carry_from(self, index: int) -> FrameFeatures | None:
        """The previous frame to run the loop against (None: start a new sequence)."""
        if not (self.cfg.stereo_carry and self.cfg.refine == "field") or self._prev is None:
            return None
        return self._prev if index > self._prev.index else None

    def features_from_detections(self, det: StereoDetections, disparity: np.ndarray | None = None,
                                 disparity_right: np.ndarray | None = None,
                                 appearance: tuple[np.ndarray, np.ndarray] | None = None,
                                 cues: StereoCues | None = None) -> FrameFeatures:
        """Stereo matches of one frame's detections. ``disparity``: dense-stereo disparity of every
        left keypoint (image px, NaN = unknown), the prior of ``stereo_prior="sgbm"`` (computed by
        :meth:`features` from the images); without it the ``refine`` method is used.
        ``disparity_right``: the right image's at every right keypoint (``sgbm_lr_tol_px``).
        ``appearance``: patch descriptors (left, right) of the keypoints (``prior_score="learned"``,
        ``temporal_min_ncc``; :func:`seedmap.associate.disparity.patch_descriptors`); the right ones
        may be None (temporal verification only). ``cues``: what ``prior_score="mlp"`` scores
        (:class:`StereoCues`, built by :meth:`features`)."""
        t0, c0 = time.perf_counter(), time.process_time()
        kl = np.asarray(det.left.keypoints, np.float64).reshape(-1, 2)
        kr = np.asarray(det.right.keypoints, np.float64).reshape(-1, 2)
        s = full_res_scale(self.calib.width)
        sums = _full_res_sums(kl, kr, s, self.cfg)
        prev = self._carry_from(det.index)
        timings: dict[str, float] = {}
        step = None
        if prev is None:
            both = appearance is not None and appearance[1] is not None
            hist = self._history(det.index, kl, sums[0], disparity, cues)
            if hist is not None:
                timings["temporal_early"] = (time.perf_counter() - t0) * 1e3
            m = match_stereo_keypoints(kl, kr, self.calib.width, self.gates, self.cfg, sums=sums, disparity=disparity,
                                       disparity_right=disparity_right, appearance=appearance if both else None,
                                       cues=cues, history=hist)
            if self.cfg.stereo_carry:  # a new sequence: no constant-velocity prediction from the old one
                self._last_shift = self._last_shift_v = None
        else:
            use = self.cfg.temporal_prediction or self.cfg.neighbours == "overlap"
            step = loop_associate(prev.kp_left, prev.kp_right, self._prev_candidates, kl, kr, self.calib.width,
                                  self.gates,
                                  self.cfg, self._last_shift if use else None, self._last_shift_v if use else None,
                                  sums_prev=(self._cached_sums(prev.kp_left), self._prev_sums_right), sums_cur=sums,
                                  prev_track=self._prev_track, prev_flow=self._prev_flow)
            m = step.stereo
            timings.update(step.cpu_ms)
            self._update_shift(prev.kp_left, kl, step.temporal)
        timings["stereo_match"] = (time.perf_counter() - t0) * 1e3
        timings["stereo_match_cpu"] = (time.process_time() - c0) * 1e3
        f = FrameFeatures(
            index=det.index, timestamp=det.timestamp, kp_left=kl, kp_right=kr, stereo=m,
            seed_ids_left=det.left.seed_ids, seed_ids_right=det.right.seed_ids, timings_ms=timings,
        )
        self._remember(f.kp_left, sums[0])
        self._hist_prev = (f, cues.right) if (self.cfg.stereo_history and cues is not None) else None
        if appearance is not None:
            self._patches = [*self._patches[-1:], (f.kp_left, appearance[0])]
        if self.cfg.stereo_carry:
            self._prev, self._prev_sums_right = f, sums[1]
            self._prev_track = None if step is None else step.track
            self._prev_candidates = m if step is None else step.candidates
            self._prev_flow = None
            if step is not None and len(step.temporal):
                t = step.temporal
                self._prev_flow = (kl[t.idx_b], kl[t.idx_b] - prev.kp_left[t.idx_a])
            self._loop = None if step is None else (prev, f, step)
        return f

    def _history(self, index: int, kl: np.ndarray, sums_left: np.ndarray, disparity: np.ndarray | None,
                 cues: StereoCues | None) -> StereoHistory | None:
        """``stereo_history``: the temporal matches of the previous frame's left keypoints to ``kl``
        (the frame ``index``), computed now, before this frame's stereo matching, by the temporal
        network (it needs only the dense disparity, not the stereo matches; kept for the
        ``match_temporal`` call that follows), as a :class:`StereoHistory`; None without a
        previous frame."""
        self._early_temporal = None
        if not self.cfg.stereo_history or disparity is None or cues is None or self._hist_prev is None:
            return None
        prev, right_prev = self._hist_prev
        ta = self._cached_temporal_inputs(prev.kp_left)
        if index != prev.index + 1 or ta is None:
            return None
        pred, pred_v = self._prediction()
        ia, ib, x = temporal_cue_candidates(prev.kp_left, kl, self.calib.width, self.gates, self.cfg, ta,
                                            TemporalInputs(cues.left, np.asarray(disparity, np.float64)), pred, pred_v,
                                            (self._cached_sums(prev.kp_left), sums_left))
        tm = self._temporal_assign(ia, ib, x, len(prev.kp_left), len(kl))
        self._early_temporal = (prev, index, tm)
        return StereoHistory(prev.kp_left, prev.kp_right, prev.stereo, tm, right_prev)

    def _temporal_assign(self, ia: np.ndarray, ib: np.ndarray, x: np.ndarray, n: int, m: int) -> Matches:
        """The temporal network's matches among the candidates ``(ia, ib)`` with cue rows ``x``."""
        t = score_model(self.cfg.temporal_score_model, "temporal").logits(x) if len(ia) else np.zeros(0)
        return assign_logits(ia, ib, t, n, m, self.cfg.temporal_mlp_min_logit, self.cfg.temporal_mlp_margin)

    def features(self, frame: StereoFrame) -> FrameFeatures:
        if self.detector is None:
            raise SeedmapError("the seeds matcher needs a detector to turn images into keypoints")
        t0 = time.perf_counter()
        det = self.detector.detect_stereo(frame)
        t_det = (time.perf_counter() - t0) * 1e3
        disp, disp_r, d_img, t_prior = None, None, None, {}
        if self.cfg.stereo_prior == "sgbm" and self._carry_from(det.index) is None:
            disp, disp_r, d_img, t_prior = self._dense_prior(frame, det)
        app, cues = None, None
        mlp = self.cfg.prior_score == "mlp"
        if disp is not None and (mlp or self.keep_inputs):
            c0, t0 = time.process_time(), time.perf_counter()
            w, pp = self.calib.width, self.cfg.patch_px
            cues = StereoCues(image_cues(frame.left, det.left.keypoints, det.left.ellipses, w, pp),
                              image_cues(frame.right, det.right.keypoints, det.right.ellipses, w, pp),
                              d_img)
            mid = self._patch_size()
            # the learned score and the temporal NCC use the middle-size patches
            app = (cues.left.patches[mid], None if mlp else cues.right.patches[mid])
            t_prior["appearance_cpu"] = (time.process_time() - c0) * 1e3
            t_prior["appearance"] = (time.perf_counter() - t0) * 1e3
        elif self._needs_appearance():
            from seedmap.associate.disparity import patch_descriptors

            c0, t0 = time.process_time(), time.perf_counter()
            size = self._patch_size()
            scored = self.cfg.stereo_prior == "sgbm" and self.cfg.prior_score == "learned"
            app = (patch_descriptors(frame.left, det.left.keypoints, size),
                   patch_descriptors(frame.right, det.right.keypoints, size) if scored else None)
            t_prior["appearance_cpu"] = (time.process_time() - c0) * 1e3
            t_prior["appearance"] = (time.perf_counter() - t0) * 1e3
        f = self.features_from_detections(det, disparity=disp, disparity_right=disp_r, appearance=app,
                                          cues=cues if mlp else None)
        if self.keep_inputs:
            self.last_stereo_inputs = (det, disp, cues)
        if self.cfg.temporal_score == "mlp":
            c0, t0 = time.process_time(), time.perf_counter()
            left = cues.left if cues is not None else image_cues(frame.left, det.left.keypoints, det.left.ellipses,
                                                                 self.calib.width, self.cfg.patch_px)
            d = disp
            if d is None:  # no dense prior: the disparity of each left keypoint's stereo match
                d = np.full(len(f.kp_left), np.nan)
                d[f.stereo.idx_a] = f.kp_left[f.stereo.idx_a, 0] - f.kp_right[f.stereo.idx_b, 0]
            self._temporal_inputs = [*self._temporal_inputs[-1:], (f.kp_left, TemporalInputs(left, d))]
            t_prior["temporal_cues_cpu"] = (time.process_time() - c0) * 1e3
            t_prior["temporal_cues"] = (time.perf_counter() - t0) * 1e3
        for k, v in t_prior.items():  # the prior is part of the stereo association's cost
            f.timings_ms[k] = v
            if k.endswith("_cpu"):
                f.timings_ms["stereo_match_cpu"] += v
            else:
                f.timings_ms["stereo_match"] += v
        f.timings_ms["detect"] = t_det
        if disp is not None:
            m = f.stereo
            self._disp_known = (det.index, f.kp_left[m.idx_a, 0] - f.kp_right[m.idx_b, 0])
        return f

    def _needs_appearance(self) -> bool:
        """Whether patch descriptors are used (learned stereo score or temporal NCC verification)."""
        c = self.cfg
        return (c.stereo_prior == "sgbm" and c.prior_score == "learned") or c.temporal_min_ncc > -1.0

    def _patch_size(self) -> int:
        """Side of the NCC patches in image px: ``patch_px`` scaled to the image width, odd, >= 3."""
        return patch_side(self.calib.width, self.cfg.patch_px)

    def _cached_patches(self, kp: np.ndarray) -> np.ndarray | None:
        for arr, desc in self._patches:
            if arr is kp:
                return desc
        return None

    def _dense_prior(self, frame: StereoFrame, det: StereoDetections
                     ) -> tuple[np.ndarray | None, np.ndarray | None, np.ndarray | None, dict[str, float]]:
        """SGBM disparity of every left keypoint (image px, NaN = unknown), of every right keypoint
        (only with ``sgbm_lr_tol_px > 0``, else None), the left image's dense disparity map (the cues
        of ``prior_score="mlp"``) and the timings; all three None when SGBM did not run.

        The disparity range searched comes from the previous frame's stereo matches when this frame
        follows it, else from a keypoint-only matching of this frame (``refine`` method)."""
        from seedmap.associate.disparity import disparity_at, disparity_search_range, sgbm_disparity

        t0, c0 = time.perf_counter(), time.process_time()
        kl = np.asarray(det.left.keypoints, np.float64).reshape(-1, 2)
        kr = np.asarray(det.right.keypoints, np.float64).reshape(-1, 2)
        if len(kl) == 0 or len(kr) == 0:
            return None, None, None, {}
        s = full_res_scale(self.calib.width)
        g = self.gates.scaled(self.calib.width)
        known = None
        if self._disp_known is not None and self._disp_known[0] == det.index - 1:
            known = self._disp_known[1]
        rng = None if known is None else disparity_search_range(
            known, self.cfg.sgbm_margin_px / s, g.stereo_min_disparity_px, self.cfg.sgbm_max_disparities)
        if rng is None:
            m0 = match_stereo_keypoints(kl, kr, self.calib.width, self.gates, self.cfg)
            rng = disparity_search_range(kl[m0.idx_a, 0] - kr[m0.idx_b, 0], self.cfg.sgbm_margin_px / s,
                                         g.stereo_min_disparity_px, self.cfg.sgbm_max_disparities)
        if rng is None:
            return None, None, None, {}
        d_img = sgbm_disparity(frame.left, frame.right, rng[0], rng[1], self.cfg.sgbm_block, self.cfg.sgbm_uniqueness)
        d = disparity_at(d_img, kl)
        d_r = None
        if self.cfg.sgbm_lr_tol_px > 0:  # the right image's disparity: SGBM of the mirrored pair
            r_img = sgbm_disparity(frame.right[:, ::-1], frame.left[:, ::-1], rng[0], rng[1], self.cfg.sgbm_block,
                                   self.cfg.sgbm_uniqueness)[:, ::-1]
            d_r = disparity_at(r_img, kr)
        return d, d_r, d_img, {"stereo_prior": (time.perf_counter() - t0) * 1e3, "stereo_prior_cpu": (time.process_time() - c0) * 1e3}

    def _update_shift(self, ka: np.ndarray, kb: np.ndarray, m: Matches) -> None:
        if len(m) >= 5:
            d = kb[m.idx_b] - ka[m.idx_a]
            self._last_shift = float(np.median(d[:, 0]))
            self._last_shift_v = float(np.median(d[:, 1]))

    def _cached_temporal_inputs(self, kp: np.ndarray) -> TemporalInputs | None:
        for arr, ti in self._temporal_inputs:
            if arr is kp:
                return ti
        return None

    def temporal_candidates(self, prev: FrameFeatures, cur: FrameFeatures
                            ) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        """The learned temporal score's candidates and cue rows of ``prev`` -> ``cur``
        (:func:`temporal_cue_candidates` with this matcher's prediction and caches), or None when
        the frames' :class:`TemporalInputs` are not known (``temporal_score`` not "mlp", or frames
        not built by :meth:`features`). Used by :meth:`match_temporal` and the score fit."""
        ta, tb = self._cached_temporal_inputs(prev.kp_left), self._cached_temporal_inputs(cur.kp_left)
        if ta is None or tb is None:
            return None
        pred, pred_v = self._prediction()
        sums = (self._cached_sums(prev.kp_left), self._cached_sums(cur.kp_left))
        return temporal_cue_candidates(prev.kp_left, cur.kp_left, self.calib.width, self.gates, self.cfg, ta, tb,
                                       pred, pred_v, sums)

    def _prediction(self) -> tuple[float | None, float | None]:
        """The constant-velocity prediction (u, v) of the temporal shift, when the config uses one."""
        use = self.cfg.temporal_prediction or self.cfg.neighbours == "overlap"
        return (self._last_shift if use else None), (self._last_shift_v if use else None)

    def match_temporal(self, prev: FrameFeatures, cur: FrameFeatures) -> Matches:
        if self._loop is not None and self._loop[0] is prev and self._loop[1] is cur:
            return self._loop[2].temporal  # computed with cur's stereo by the loop
        pred, pred_v = self._prediction()
        sums = (self._cached_sums(prev.kp_left), self._cached_sums(cur.kp_left))
        early = self._early_temporal
        cand = None
        if early is None or early[0] is not prev or early[1] != cur.index:
            early = None
            cand = self.temporal_candidates(prev, cur) if (self.cfg.temporal_score == "mlp"
                                                           and self.cfg.refine == "field") else None
        if early is not None:  # stereo_history: computed before cur's stereo matching (same network)
            m = early[2]
        elif cand is not None:
            m = self._temporal_assign(*cand, len(prev.kp_left), len(cur.kp_left))
        else:
            m = match_temporal_keypoints(prev.kp_left, cur.kp_left, self.calib.width, self.gates, self.cfg, pred,
                                         pred_v, sums=sums)
        if self.cfg.temporal_min_ncc > -1.0 and len(m):
            da, db = self._cached_patches(prev.kp_left), self._cached_patches(cur.kp_left)
            if da is not None and db is not None:
                from seedmap.associate.disparity import patch_ncc

                keep = patch_ncc(da, db, m.idx_a, m.idx_b) >= self.cfg.temporal_min_ncc
                m = Matches(m.idx_a[keep], m.idx_b[keep], m.cost[keep])
        self._update_shift(prev.kp_left, cur.kp_left, m)
        return m

    def reset(self) -> None:
        self._last_shift = None
        self._last_shift_v = None
        self._sums = []
        self._prev = None
        self._prev_sums_right = None
        self._loop = None
        self._prev_track = None
        self._prev_candidates = Matches()
        self._prev_flow = None
        self._disp_known = None
        self._patches = []
        self._temporal_inputs = []
        self._hist_prev = None
        self._early_temporal = None


#: cue columns of each :class:`ScoreModel` kind
_CUE_NAMES_OF_KIND: dict[str, tuple[str, ...]] = _cue_names_of_kind()
