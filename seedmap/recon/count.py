"""Counting seeds: multi-view association of 2D detections (default), or de-duplication of
per-view 3D seed centres.

Method ``multiview`` (default): counts from the 2D detections of every view (left AND right
image) and the registered camera poses; no per-detection SGBM depth is used (SGBM depth is missing
for many seed-sized patches and has heavy tails, which made ghost and missing seeds).

0a. *Scale-aware tolerances* (``mv_scale_ref_px`` > 0; on in the ``gt`` detector profile): the pixel
   tolerances named in ``mv_scale_keys`` (row difference of a stereo pair, link and reprojection
   tolerances, growing radius) are multiplied by (median left detection size of the scan /
   ``mv_scale_ref_px``) ** ``mv_scale_power``, clipped to [``mv_scale_min``, ``mv_scale_max``]. A partly
   hidden seed's visible centre differs between the left and the right image and between views by a
   fraction of its size: on panicle 114 (median ``gt`` keypoint size 9.2 px vs 6.9 px on 111) 16 % of
   the true left/right pairs lie more than 2 px apart in rows (111: 3 %) and only 66 % were chosen
   (111: 88 %), so fixed pixel tolerances under-counted it by 17.7 %. With ``gt`` (reference 7 px,
   power 1.5; tuning panicles 95-100 + 111-115) MAPE 4.6 % -> 2.9 %, 114: -17.7 % -> -6.2 %. The
   support scale ``mv_support_sigma_px`` is not scaled (it lets ghost matches gather support: +2 to
   +7 % on the large-seeded panicles). The detectors' ellipse sizes barely follow the seed size, so
   their profiles keep fixed pixels (seedmap.recon.config.DETECTOR_PROFILES).
0. *Optional* (``mv_merge_px`` > 0; off by default): keypoints of one image closer than
   ``mv_merge_px`` are joined into their mean first -- a detector that fires twice on one seed
   (the CNN ``fast`` detector does on ~30 % of the seeds, peaks 1-3 px apart) otherwise makes two
   consistent tracks per seed. Held-out (panicles 101-110, seeds registration, vs countable):
   ``fast`` 45.7 % -> 11.1 % MAPE with ``mv_merge_px=3`` + ``mv_surface_tol=0.005``; the ``gt``
   detector 7.4 % -> 10.6 %, so it is not the default but part of the ``fast`` detector profile
   (below).
   ``mv_merge_size`` > 0 scales that radius with the detections' own size (left pairs closer than
   ``mv_merge_size`` x the smaller of their two sizes; right keypoints x the image's median left
   size). Session 7b (issue #6, arm network on auto-exposed scans, tuning panicles 95-99 + 111-115):
   two ``fast`` keypoints on one seed lie 3.5-3.9 px apart (median; 0.45-0.6 of the smaller
   detection size), keypoints on two different seeds 5-6 px (p5; 0.8-0.9 sizes), so a per-image
   merge that catches half the duplicates also joins neighbours: ``fast`` MAPE 5.9 % -> 6.4 / 6.7 /
   8.5 % at 0.3 / 0.4 / 0.5 (the bright panicles lose seeds: 98 -6.0 -> -10.5 %), so it stays off.
1. **Stereo matches, verified by the neighbours.** In view k every left keypoint may pair with any
   right keypoint on the same row (``mv_stereo_dv_px``) whose disparity lies in the depth range
   (rectified pair: the epipolar line is the row). Each candidate pair triangulates to one 3D
   point; it is projected into the left and right images of the ``mv_verify_views`` views on
   each side (registered poses) and scores sum exp(-e^2 / 2 sigma^2) over those images, e = distance
   (px) to the nearest detection there (``mv_support_sigma_px``). A true match is confirmed by
   most neighbouring images, a wrong disparity lands on background or a random seed. One-to-one
   matches: ``scipy.optimize.linear_sum_assignment`` maximising the support, pairs with support
   >= ``mv_min_support`` kept.
   *Row residual* (``mv_row_sigma_px`` > 0; in the ``fast`` profile since session 8): the assignment
   maximises support x exp(-dv^2 / 2 sigma^2), dv = row difference of the pair. Session 8 (issue #6,
   ``fast`` on the tuning panicles 95-99 + 111-115, every left/right keypoint labelled with the GT seed
   under it): a counted track that matches no new GT seed is a *ghost* -- 2-view tracks with support
   ~1.9 whose left and right keypoints sit on different seeds (79-90 % of their stereo matches; 53 %
   of their left keypoints are a second detection on a seed on the dark 115, 21 % on the bright 111),
   3538 ghosts on the ten panicles, 24 % of the countable seeds on 115 and 11 % on 111, growing with the
   share of seed-views that carry two keypoints (+1.0 % ghosts per +1 % such seed-views). Against them
   stand 4267 *missed* countable seeds (7 % on 97 ... 31 % on 114): most have a left AND right keypoint
   in at most one view (the detector misses them in the other image), and where both exist their true
   pair has little support (median 0.8) and loses the assignment to a neighbour's keypoint on the
   same row band (the ``fast`` row tolerance is 4 px x the size scale, 5.6-6.2 px; true pairs differ by
   1.1 px median). The count is the balance of the two, so removing ghosts alone lowers every count:
   dropping 2-view tracks whose point lies > 3 diameters behind the local seed surface, or tracks whose
   left keypoints sit within 0.6 sizes of a longer track's in half their views, both took 5-15 % off
   the dark 115 and the bright 111 alike. The row weighting (sigma 1.5 px) removes ghosts AND recovers missed seeds
   (3538 / 4267 -> 2823 / 4021) at a lower balance (signed -1.7 -> -3.9 %), which the second linking pass
   (step 2b, ``mv_relink_px`` 10, ``mv_relink_min_support`` 1.5) restores: tuning MAPE 5.38 -> 4.84 %
   (signed -1.7 -> -2.2 %; ghosts 3097, missed 3912). Frozen, then run once per never-tuned set
   (``--recount``, MAPE vs countable, session 7b -> 8): 101-110 5.27 -> 4.33 %, 116-125 9.68 -> 8.34 %,
   150-159 4.11 -> 4.72 %, 160-169 10.37 -> 8.56 %, 170-179 5.28 -> 5.38 % (the 50 together 6.9 -> 6.3 %;
   dark varieties 161 +26.4 -> +19.2 %, 124 +20.2 -> +15.9 %, 125 +14.5 -> +13.1 %), and on panicles
   180-189 rendered after the freeze 4.43 -> 3.32 % (``gt`` 1.63 %). The large-seeded under-count stays
   (114 -16.0 -> -17.0 %, 119 -15.0 -> -16.1 %). Tried and not adopted: two-view tracks of the left
   keypoints no counted track holds (pairs of views, both-left triangulation, depth near the counted
   seeds around): 10-20 % of what they added was a missed seed.
   *Duplicate groups* (``mv_dup_size`` > 0; off): left keypoints of one image closer than ``mv_dup_size``
   x the smaller of their two detection sizes enter the assignment as one row (the group's best
   candidate per right keypoint), so a second detection on a seed makes no stereo match of its own.
   It halves the dependence of the count error on the share of duplicated seed-views (slope over the ten
   tuning panicles 41 -> 21 % per unit with the row weighting) but lowers every count (0.5 sizes: tuning
   signed -1.7 -> -6.6 %, MAPE 7.4 %), and no recall-raising setting tried (support sigma 1.5-2 px,
   min support 0.25-1, wider link/reprojection/growing tolerances, lag 4, the relink pass) brought the
   MAPE below the row weighting + relink alone (0.3 sizes with them: 4.82 % but 98 -8.3 %, 114 -17.9 %).
   *Appearance* (``mv_appearance_weight`` > 0; opt-in, session 11): every keypoint gets a context descriptor
   when the view is prepared (``mv_desc_size`` > 0: the square of half-width ``mv_desc_size`` x the view's
   median detection size around it, box-averaged to ``mv_desc_grid``^2 cells per colour channel, zero-mean and
   unit-norm; :func:`context_descriptors`), and the assignment weight is multiplied by
   exp(beta (ncc - 1)), ncc = the two descriptors' dot product; candidates below ``mv_appearance_min`` are
   dropped. On the arm scans (baseline 0.11 m at 0.27 m, so the two images see a seed ~25 degrees apart) the
   seed alone looks alike in both images, its neighbourhood does not: over the stereo candidates of panicle
   96 (``fast`` keypoints labelled with the GT seed under them) ncc tells a true pair from a wrong one with
   AUC 0.78 / 0.83 / 0.87 for grey patches of 23 / 31 / 51 px, 0.895 for 61-px colour patches and 0.88 with
   the setting below (the row residual: 0.82; benchmarks/stereo_ncc_auc.py). Chosen on tuning panicles 95-99, 111-115 and red 310-315 only (size 6, grid 15, beta 5:
   MAPE 5.32 -> 4.53 %), it raised the count of every held-out panicle by 2.8 +- 1.2 points without
   narrowing the spread (95 panicles: std of the signed error unchanged), so it is in no profile. The
   per-panicle spread follows the detector's recall: on the under-counted panicles only 78-81 % of the
   countable seeds have a left and a right ``fast`` keypoint in >= 2 views (the counter cannot count the
   rest), on the over-counted 213 and 97 95-96 %.
   *Optional surface-depth check* (``mv_surface_tol`` > 0; off by default): a candidate whose depth
   lies more than ``mv_surface_tol`` behind (or ``mv_surface_front_tol`` in front of) the SGBM
   surface depth at its left keypoint (``StereoKeypoints.left_disp``, window median) is dropped
   before the assignment; keypoints without valid SGBM (about half of them) keep all candidates.
   It removes wrong-depth matches of noisy detectors (``fast`` held-out 45.7 % -> 34.6 % MAPE at
   5 mm) but also true matches where SGBM is off (SGBM - keypoint depth on ``gt`` matches of
   >= 3-view tracks: p5 -8.6 mm, p95 +3.7 mm), so it raises the undercount of ``gt`` (7.4 -> 10.2 %).
2. **Cross-view links.** A stereo match a of view k and b of view k+lag (lag 1..``max_lag``) are
   linked when a's 3D point projects within ``mv_link_px`` of b's left AND right keypoints and
   b's point onto a's (symmetric epipolar/reprojection test; each b keeps its cheapest a). Links
   are merged nearest views first, cheapest first (union-find) under the cannot-link rule: one
   view contributes at most one detection to a track.
   *Joint test* (``mv_link_joint``; on in the ``gt`` detector profile): the point triangulated from
   the four rays of a and b must reproject within ``mv_link_px`` into all four images. A partly
   hidden seed's visible centre differs between the left and the right image, so its own stereo
   depth is off by millimetres (correct stereo matches of seeds the plain test left unlinked: 3D
   points ~3 mm apart, median reprojection into the next view 1.1 px left / 2.7 px right); the joint
   point shares that error between both views. Tuning panicles 95-100 with ``gt``: MAPE vs
   countable 8.8 % -> 3.5 %. With the ``fast`` / ``fast-classic`` detectors it links ghost matches
   too (fast-classic 19 % -> 56 %), so it is not their default.
   *Optional second pass* (``mv_relink_px`` > ``mv_link_px``; off by default): observations whose
   track still has fewer than ``min_observations`` views are linked with the wider tolerance
   ``mv_relink_px``, only between stereo matches of support >= ``mv_relink_min_support``. On the
   tuning panicles 99/100 (gt detections) it recovers ~1 point of the undercount, but it raises the
   overcount of the noisy fast-classic detector by about as much, so it is not the default. Since
   session 8 the ``fast`` profile runs it (10 px, support >= 1.5) together with the row weighting of
   step 1, which had removed more ghosts than it recovered seeds (step 1 above).
3. **Triangulation.** Each track is triangulated from all its rays (left and right camera of
   every view; linear least squares, the point closest to all rays); observations reprojecting
   farther than ``mv_max_reproj_px`` are dropped from their track and it is re-triangulated --
   only the worst one of each track per round (``mv_drop_worst_only``, up to ``mv_reproj_rounds``):
   one wrong observation pulls the point and used to take a whole well-seen track with it.
3b. **Growing** (``mv_grow_px`` > 0). A track of >= ``min_observations`` views projects its point into
   the views it lacks that have views of the track on both sides within ``mv_grow_views``
   (``mv_grow_fill_only``: beyond the end of its arc a seed turns away and its foreshortened
   neighbour lands where it would project). Where an unambiguous left keypoint (no other within
   ``mv_grow_unique_px``) and a right keypoint on the same row lie within ``mv_grow_px`` it claims
   the pair -- taking it from its current stereo match only when that match's track has fewer views
   (a ghost match built from this seed's left keypoint and a neighbour's right one, or a fragment).
   Tracks with more views choose first; then re-triangulation (``mv_grow_passes`` rounds). It removes
   ghost tracks that counted a seed twice (``gt``, tuning panicles 99/100: 320 -> 204 doubles).
4. **Count.** Tracks supported by >= ``min_observations`` views, after a 3D de-duplication that
   joins tracks closer than ``mv_dedupe`` x the median seed diameter and sharing no view
   (fragments of one seed, e.g. seen from two arcs of views with a gap between), and -- with
   ``mv_dedupe_shared`` > 0 -- tracks closer than that many median diameters even when they share
   views: a detector that fires more than once on one seed makes two consistent tracks through the
   same views (on the arm-scan seeds, larger than the row-image seeds the detectors were trained on,
   ~50-60 % of ``fast`` / ``fast-classic`` keypoints have their nearest neighbour on the same seed,
   2.5-3.9 px away; ``gt`` 4-6 %). Session 7b (issue #6, dark varieties): with the ``fast`` profile's
   earlier 0.4 diameters, pairs of counted tracks whose left keypoints lie mostly on ONE true seed
   are 0.63 median diameters apart on the dark panicle 115 (median of 253 such pairs within 1.5
   diameters; the bright 111: 43 pairs), and joining up to 0.6 diameters takes 163 such pairs against
   8 pairs of two different seeds on the tuning panicles 96, 98, 111, 114, 115 (0.8: 232 against 69).
   *Track-sized joins* (``mv_dedupe_size="track"``; off): both join radii are measured in the mean of the
   two tracks' own median diameters instead of the scan's median seed (a large seed among small ones
   whose two detections lie farther apart). Session 10 (issue #6: ``fast`` over-counts red large-seeded
   varieties by +10 %): on the tuning panicles 95-99 + 111-115 plus the red tuning-only 310-315 (shipped
   arm network) MAPE 4.95 -> 4.88 % with 0.7 diameters (95-99 + 111-115 4.84 -> 4.88, red 5.13 -> 4.88),
   the best of seven counter settings tried there (scan-sized 0.7: 4.89; ``mv_scale_max`` 2.0: 5.05;
   ``mv_dup_size`` 0.3 / 0.4: 5.05 / 5.44), frozen and run once on the 70 never-tuned + fresh 190-199
   panicles: 6.03 -> 6.12 %, red large-seeded +10.2 -> +10.9 %, so it stays off. No join radius moved
   the over-counted red tuning panicle 311 (+9.1 %) by more than a point: its surplus tracks are not two
   tracks on one seed.

**View spacing (session 13).** The settings above were chosen on 24-view scans (views 15 degrees apart). On 36-view
scans (10 degrees) of panicles 530-539 the counter over-counted by +22.5 % with the ``gt`` oracle and +17.5 % with
``fast``: neighbouring views see a wrong left/right pairing from nearly the same direction, so it gathers support and
links into a track (on 534, wrong-partner stereo matches 23 -> 31 %, tracks on an already counted seed 136 -> 504).
Verifying at about the 24-view angles instead (offsets 2 and 3) did not help (``gt`` +24.2 %), more linking lag
neither (``fast`` +18.3 % at lag 5). Raising the minimum supports did: ``support_shift`` adds
``mv_support_density_gain`` x (15 / spacing - 1) to ``mv_min_support`` and ``mv_relink_min_support`` when the views
are >= 5 % closer than ``mv_support_ref_deg`` (36 views: +1.5). Gain 3.0, the best of 2.5-3.5 for both detectors on
those ten panicles (MAPE ``gt`` 22.5 -> 2.95 %, ``fast`` 17.5 -> 4.78 %); 24-view scans are untouched (shift 0). On
fresh 36-view panicles 540-549 it overshoots: ``gt`` 28.0 -> 8.57 %, ``fast`` 14.1 -> 12.76 % (README). Sparser scans
are not handled: at 12 views (30 degrees) both detectors under-count by about 13 % (``gt`` improves with a lower
support, ``fast`` does not), and :func:`count_multiview` warns.

**Detector profiles.** ``CountConfig.detector_profiles`` holds key=value overrides per detector name
that the pipeline and ``seedmap count`` apply on top of the count settings
(:meth:`CountConfig.for_detector`; ``count.detector_profile=false`` turns them off): ``gt`` joint
links at 1.5 px; ``fast`` (with the arm-scan network ``cnn.domain=arm`` that the pipeline selects)
doubles the row, link, reprojection and growing tolerances (session 6) and, since session 7 (arm scans
exposed for their stand-off), scales them with the seed size like ``gt`` (reference 6 px), joins tracks
sharing views within 0.6 diameters (0.4 before session 7b), accepts stereo matches with support 0.5 and no longer merges
keypoints, and since session 8 (issue #6) weights stereo candidates by their row residual (1.5 px) and
links the stereo matches left without a partner view in a second pass (10 px, support >= 1.5);
``fast-classic`` joins them within 1.0 diameter; ``gt`` scales its pixel tolerances with the
seed size (step 0a, session 5). Chosen on
the tuning panicles 95-100 (and 111-115 since session 5) only (seedmap.recon.config.DETECTOR_PROFILES).
A detector without a profile gets the plain settings.

Every view contributes one 3D centre per detected seed (in the registered world frame), so a seed
seen from ``n`` views appears as a tight cloud of ``n`` observations.

Method ``rays`` (session-2 default): a per-view seed centre is precise ACROSS its viewing ray (keypoint,
~0.2 mm at 0.3 m) but not ALONG it (stereo depth of a 3 mm seed: ~1 mm core, a long tail), so two
observations are compared by the Mahalanobis distance under covariances elongated along their rays
(``sigma_lateral`` across, ``sigma_depth`` along, needs each observation's camera centre). Pairs
of views up to ``max_lag`` steps apart within ``gate_chi2`` are merged (union-find) nearest views
first -- their rays are nearly parallel, so depth errors hardly matter -- and by increasing distance
within a lag, under the cannot-link rule below. A group seen from ``min_observations`` distinct
views is one seed; its position is the information-weighted mean (rays from different directions
fix the depth). A seed hidden for more than ``max_lag`` views in between (seen from two separate
arcs) gives two groups: ``merge_passes`` passes join counted groups that share no view and whose
information-weighted positions agree within ``merge_chi2`` (group covariances).

Method ``tracks``: observations of views up to ``max_lag`` steps apart around the circle
are linked when they are mutual nearest neighbours within ``link_radius``; links are merged
shortest first (union-find) under a cannot-link rule -- one view sees a seed at most once, so two
groups that share a view are never merged (this is what keeps touching seeds ~4 mm apart
separate even where a few bad centres scatter by several mm). A group supported by at least
``min_observations`` distinct views is one seed.

Method ``density`` (session-1 default; DBSCAN, density smoothing, local maxima):

1. **DBSCAN** (Open3D ``cluster_dbscan``, ``eps`` ~ one seed diameter) splits the observations into
   spatially separate groups and marks isolated observations as noise (kept as singleton groups;
   step 4 decides whether they count).
2. **Density smoothing**: inside a group every observation gets a Gaussian kernel density
   (sigma = ``bandwidth``, ~ the registration + stereo scatter) summed over its neighbours.
3. **Local maxima**: observations are visited by decreasing density; one becomes a seed centre
   when no stronger centre lies within ``separation`` x the median seed diameter (non-maximum
   suppression -- touching seeds are one diameter apart, duplicates of one seed far closer).
   Every observation is then assigned to its nearest centre.
4. A centre counts as a seed when its observations come from at least ``min_observations``
   distinct views. Position = mean of its observations, size = median observed diameter.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from seedmap.geometry import transform_points
from seedmap.recon.config import CountConfig


@dataclass
class SeedCount:
    """Counted seeds: positions (m, world), diameters (m), supporting views, and per-observation
    assignment (index into the counted seeds, -1 = not counted)."""

    xyz: np.ndarray  # (S, 3)
    diameter: np.ndarray  # (S,)
    n_views: np.ndarray  # (S,)
    assignment: np.ndarray  # (N_obs,)
    spread: np.ndarray  # (S,) RMS distance of the observations to the centre (m)

    @property
    def count(self) -> int:
        return len(self.xyz)


def dbscan(xyz: np.ndarray, eps: float, min_points: int) -> np.ndarray:
    """Open3D DBSCAN labels (-1 = noise)."""
    import open3d as o3d

    if len(xyz) == 0:
        return np.zeros(0, np.int64)
    p = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.asarray(xyz, np.float64)))
    return np.asarray(p.cluster_dbscan(eps=eps, min_points=min_points, print_progress=False), np.int64)


def count_seeds(xyz: np.ndarray, view: np.ndarray, diameter: np.ndarray, cfg: CountConfig,
                origin: np.ndarray | None = None) -> SeedCount:
    """De-duplicate seed observations (world centres ``xyz`` (N, 3) m, their ``view`` ids and
    observed ``diameter`` (m)) into one entry per physical seed (methods in the module docstring).
    ``origin`` (N, 3) m: the camera centre each observation was seen from (method ``rays`` needs it:
    the depth along that ray is far less certain than the position across it)."""
    if cfg.method == "multiview":
        raise ValueError("count method 'multiview' counts 2D detections: use count_multiview (the 3D methods "
                         "here are rays, tracks and density)")
    if cfg.method == "rays":
        if origin is None:
            raise ValueError("count method 'rays' needs the camera centre of every observation (origin)")
        return count_rays(xyz, view, diameter, origin, cfg)
    if cfg.method == "tracks":
        return count_tracks(xyz, view, diameter, cfg)
    xyz = np.asarray(xyz, float).reshape(-1, 3)
    view = np.asarray(view, np.int64).reshape(-1)
    diameter = np.asarray(diameter, float).reshape(-1)
    n = len(xyz)
    if n == 0:
        return SeedCount(np.zeros((0, 3)), np.zeros(0), np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0))
    groups = dbscan(xyz, cfg.dbscan_eps, cfg.dbscan_min_points)
    noise = groups < 0
    groups = groups.copy()
    groups[noise] = groups.max(initial=-1) + 1 + np.arange(noise.sum())
    sep = cfg.separation * float(np.median(diameter))
    tree = cKDTree(xyz)
    # density: Gaussian kernel over neighbours of the same group within 3 sigma
    s = cfg.bandwidth
    pairs = tree.query_pairs(3 * s, output_type="ndarray")
    dens = np.ones(n)
    if len(pairs):
        same = groups[pairs[:, 0]] == groups[pairs[:, 1]]
        pr = pairs[same]
        w = np.exp(-np.sum((xyz[pr[:, 0]] - xyz[pr[:, 1]]) ** 2, axis=1) / (2 * s * s))
        np.add.at(dens, pr[:, 0], w)
        np.add.at(dens, pr[:, 1], w)
    # greedy non-maximum suppression by decreasing density (ties broken by index: deterministic)
    order = np.lexsort((np.arange(n), -dens))
    suppressed = np.zeros(n, bool)
    centres: list[int] = []
    for i in order:
        if suppressed[i]:
            continue
        centres.append(int(i))
        nb = np.asarray(tree.query_ball_point(xyz[i], sep), np.int64)
        suppressed[nb[groups[nb] == groups[i]]] = True
    centres_a = np.asarray(centres, np.int64)
    ctree = cKDTree(xyz[centres_a])
    _, near = ctree.query(xyz)
    near = np.asarray(near, np.int64)
    # refine: mean position of each centre's members, then support by distinct views
    n_c = len(centres_a)
    pos = np.zeros((n_c, 3))
    np.add.at(pos, near, xyz)
    cnt = np.bincount(near, minlength=n_c)
    pos /= np.maximum(cnt, 1)[:, None]
    key = np.unique(near * (view.max() + 1) + view)
    nviews = np.bincount(key // (view.max() + 1), minlength=n_c)
    keep = nviews >= cfg.min_observations
    new_index = np.full(n_c, -1, np.int64)
    new_index[keep] = np.arange(keep.sum())
    assignment = new_index[near]
    diam = np.array([np.median(diameter[near == c]) for c in np.flatnonzero(keep)]) if keep.any() else np.zeros(0)
    d2 = np.sum((xyz - pos[near]) ** 2, axis=1)
    spread = np.sqrt(np.bincount(near, weights=d2, minlength=n_c) / np.maximum(cnt, 1))
    return SeedCount(pos[keep], diam, nviews[keep], assignment, spread[keep])


def count_tracks(xyz: np.ndarray, view: np.ndarray, diameter: np.ndarray, cfg: CountConfig) -> SeedCount:
    """The ``tracks`` method (module docstring): constrained linking of cross-view mutual neighbours."""
    xyz = np.asarray(xyz, float).reshape(-1, 3)
    view = np.asarray(view, np.int64).reshape(-1)
    diameter = np.asarray(diameter, float).reshape(-1)
    n = len(xyz)
    if n == 0:
        return SeedCount(np.zeros((0, 3)), np.zeros(0), np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0))
    views = np.unique(view)
    V = int(views.max()) + 1
    by_view = {int(v): np.flatnonzero(view == v) for v in views}
    trees = {v: cKDTree(xyz[i]) for v, i in by_view.items()}
    edges = []
    for a in by_view:
        for lag in range(1, cfg.max_lag + 1):
            b = (a + lag) % V
            if b == a or b not in by_view:
                continue
            ia, ib = by_view[a], by_view[b]
            dab, jab = trees[b].query(xyz[ia], distance_upper_bound=cfg.link_radius)
            dba, jba = trees[a].query(xyz[ib], distance_upper_bound=cfg.link_radius)
            ok = np.isfinite(dab)
            ka = np.flatnonzero(ok)
            kb = jab[ok]
            mutual = jba[kb] == ka
            for x, y, d in zip(ia[ka[mutual]], ib[kb[mutual]], dab[ok][mutual], strict=True):
                edges.append((float(d), int(x), int(y)))
    edges.sort()
    parent = np.arange(n)
    vmask = [1 << int(v) for v in view]  # views present in each group (python ints: any number of views)

    def find(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    for _, x, y in edges:
        rx, ry = find(x), find(y)
        if rx == ry or (vmask[rx] & vmask[ry]):
            continue
        parent[ry] = rx
        vmask[rx] |= vmask[ry]
    roots = np.array([find(i) for i in range(n)])
    uniq, comp = np.unique(roots, return_inverse=True)
    nviews = np.array([bin(vmask[r]).count("1") for r in uniq])
    keep = nviews >= cfg.min_observations
    new_index = np.full(len(uniq), -1, np.int64)
    new_index[keep] = np.arange(keep.sum())
    cnt = np.bincount(comp, minlength=len(uniq))
    pos = np.zeros((len(uniq), 3))
    np.add.at(pos, comp, xyz)
    pos /= cnt[:, None]
    d2 = np.sum((xyz - pos[comp]) ** 2, axis=1)
    spread = np.sqrt(np.bincount(comp, weights=d2, minlength=len(uniq)) / cnt)
    diam = np.array([np.median(diameter[comp == c]) for c in np.flatnonzero(keep)]) if keep.any() else np.zeros(0)
    return SeedCount(pos[keep], diam, nviews[keep], new_index[comp], spread[keep])


def _ray_covariances(xyz: np.ndarray, origin: np.ndarray, sigma_lat: float, sigma_depth: float) -> np.ndarray:
    """(N, 3, 3) covariance of each observation: ``sigma_lat`` across its viewing ray, ``sigma_depth`` along it."""
    r = xyz - origin
    r /= np.maximum(np.linalg.norm(r, axis=1, keepdims=True), 1e-12)
    return sigma_lat ** 2 * np.eye(3)[None] + (sigma_depth ** 2 - sigma_lat ** 2) * r[:, :, None] * r[:, None, :]


def count_rays(xyz: np.ndarray, view: np.ndarray, diameter: np.ndarray, origin: np.ndarray,
               cfg: CountConfig) -> SeedCount:
    """The ``rays`` method (module docstring): cannot-link agglomeration of observations under a
    ray-aligned (anisotropic) Mahalanobis distance."""
    xyz = np.asarray(xyz, float).reshape(-1, 3)
    view = np.asarray(view, np.int64).reshape(-1)
    diameter = np.asarray(diameter, float).reshape(-1)
    origin = np.asarray(origin, float).reshape(-1, 3)
    n = len(xyz)
    if n == 0:
        return SeedCount(np.zeros((0, 3)), np.zeros(0), np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0))
    if len(origin) != n:
        raise ValueError(f"origin has {len(origin)} rows for {n} observations")
    cov = _ray_covariances(xyz, origin, cfg.sigma_lateral, cfg.sigma_depth)
    # candidate pairs: Euclidean pre-filter wide enough for the depth uncertainty of both ends
    radius = min(np.sqrt(cfg.gate_chi2 * 2.0) * cfg.sigma_depth, cfg.max_pair_distance)
    pairs = cKDTree(xyz).query_pairs(radius, output_type="ndarray")
    pairs = pairs[view[pairs[:, 0]] != view[pairs[:, 1]]] if len(pairs) else np.zeros((0, 2), np.int64)
    if len(pairs):
        d = xyz[pairs[:, 0]] - xyz[pairs[:, 1]]
        S = cov[pairs[:, 0]] + cov[pairs[:, 1]]
        m2 = np.einsum("pi,pi->p", d, np.linalg.solve(S, d[:, :, None])[:, :, 0])
        V = int(view.max()) + 1
        lag = np.abs(view[pairs[:, 0]] - view[pairs[:, 1]])
        lag = np.minimum(lag, V - lag) if cfg.circular else lag
        ok = (m2 <= cfg.gate_chi2) & (lag <= cfg.max_lag)
        pairs, m2, lag = pairs[ok], m2[ok], lag[ok]
        # neighbouring views first (their rays are nearly parallel, so depth errors barely matter),
        # each lag by increasing distance
        order = np.lexsort((m2, lag))
        pairs = pairs[order]
    uf = _CannotLinkUnionFind(view)
    for x, y in pairs.tolist():
        uf.union(x, y)
    # information matrices: across-ray directions are known precisely, the depth loosely
    W = np.linalg.inv(cov)
    Wx = np.einsum("nij,nj->ni", W, xyz)
    for _ in range(cfg.merge_passes):
        if not _merge_groups(uf, xyz, W, Wx, cfg):
            break
    roots = np.array([uf.find(i) for i in range(n)])
    uniq, comp = np.unique(roots, return_inverse=True)
    nviews = np.array([bin(uf.vmask[r]).count("1") for r in uniq])
    keep = nviews >= cfg.min_observations
    new_index = np.full(len(uniq), -1, np.int64)
    new_index[keep] = np.arange(keep.sum())
    pos, _ = _group_estimates(comp, len(uniq), W, Wx)
    cnt = np.bincount(comp, minlength=len(uniq))
    d2 = np.sum((xyz - pos[comp]) ** 2, axis=1)
    spread = np.sqrt(np.bincount(comp, weights=d2, minlength=len(uniq)) / cnt)
    diam = np.array([np.median(diameter[comp == c]) for c in np.flatnonzero(keep)]) if keep.any() else np.zeros(0)
    return SeedCount(pos[keep], diam, nviews[keep], new_index[comp], spread[keep])


class _CannotLinkUnionFind:
    """Union-find over observations that refuses to join two groups seen by a common view."""

    def __init__(self, view: np.ndarray) -> None:
        self.parent = np.arange(len(view))
        self.vmask = [1 << int(v) for v in view]  # views of each group (python ints: any number of views)

    def find(self, i: int) -> int:
        parent = self.parent
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    def union(self, x: int, y: int, force: bool = False) -> bool:
        rx, ry = self.find(x), self.find(y)
        if rx == ry or (self.vmask[rx] & self.vmask[ry] and not force):
            return False  # cannot-link: one view sees a seed at most once
        self.parent[ry] = rx
        self.vmask[rx] |= self.vmask[ry]
        return True


def _group_estimates(comp: np.ndarray, n_groups: int, W: np.ndarray, Wx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Information-weighted position (G, 3) and its covariance (G, 3, 3) of each group."""
    Wsum = np.zeros((n_groups, 3, 3))
    np.add.at(Wsum, comp, W)
    b = np.zeros((n_groups, 3))
    np.add.at(b, comp, Wx)
    C = np.linalg.inv(Wsum)
    return np.einsum("gij,gj->gi", C, b), C


def _merge_groups(uf: _CannotLinkUnionFind, xyz: np.ndarray, W: np.ndarray, Wx: np.ndarray,
                  cfg: CountConfig) -> bool:
    """One pass of group-level merging: fragments of one seed seen from views more than ``max_lag``
    apart (a seed hidden for a few views in between) are joined when their information-weighted
    positions agree (``merge_chi2``) and they share no view. Returns whether anything merged."""
    roots = np.array([uf.find(i) for i in range(len(xyz))])
    uniq, comp = np.unique(roots, return_inverse=True)
    pos, C = _group_estimates(comp, len(uniq), W, Wx)
    # only groups that count already: a seed seen from two separate arcs of views
    nviews = np.array([bin(uf.vmask[r]).count("1") for r in uniq])
    counted = np.flatnonzero(nviews >= max(cfg.min_observations, 2))
    pairs = cKDTree(pos[counted]).query_pairs(cfg.merge_radius, output_type="ndarray")
    if len(pairs) == 0:
        return False
    pairs = counted[pairs]
    d = pos[pairs[:, 0]] - pos[pairs[:, 1]]
    m2 = np.einsum("pi,pi->p", d, np.linalg.solve(C[pairs[:, 0]] + C[pairs[:, 1]], d[:, :, None])[:, :, 0])
    ok = m2 <= cfg.merge_chi2
    merged = False
    for k in np.flatnonzero(ok)[np.argsort(m2[ok], kind="stable")]:
        merged |= uf.union(int(uniq[pairs[k, 0]]), int(uniq[pairs[k, 1]]))
    return merged


def naive_2d_count(per_view_counts: np.ndarray, expected_views_per_seed: float) -> float:
    """The 2D baseline: total detections over all views divided by how many views see a seed."""
    return float(np.sum(per_view_counts) / max(expected_views_per_seed, 1e-9))


# ------------------------------------------------------------------------------------------------
# method ``multiview``: 2D association across views + triangulation (module docstring)
# ------------------------------------------------------------------------------------------------


@dataclass
class StereoKeypoints:
    """The 2D seed detections of one stereo view: ``left`` (N, 2) and ``right`` (M, 2) keypoints
    (px, rectified images) and ``left_size`` (N,) the mean full ellipse axis of each left detection
    (px; gives the seed diameter once the depth is known)."""

    left: np.ndarray
    right: np.ndarray
    left_size: np.ndarray
    left_disp: np.ndarray | None = None  # (N,) SGBM disparity at each left keypoint (px, NaN = none)
    #: (N, D) / (M, D) appearance descriptors of the left / right keypoints (:func:`context_descriptors`:
    #: zero-mean, unit-norm colour context patches, so a dot product is their normalised cross-correlation)
    left_desc: np.ndarray | None = None
    right_desc: np.ndarray | None = None

    def __post_init__(self) -> None:
        self.left = np.asarray(self.left, float).reshape(-1, 2)
        self.right = np.asarray(self.right, float).reshape(-1, 2)
        self.left_size = np.asarray(self.left_size, float).reshape(-1)
        if len(self.left_size) != len(self.left):
            raise ValueError(f"StereoKeypoints: {len(self.left_size)} sizes for {len(self.left)} left keypoints")
        if self.left_disp is not None:
            self.left_disp = np.asarray(self.left_disp, float).reshape(-1)
            if len(self.left_disp) != len(self.left):
                raise ValueError(f"StereoKeypoints: {len(self.left_disp)} disparities for {len(self.left)} "
                                 "left keypoints")
        if (self.left_desc is None) != (self.right_desc is None):
            raise ValueError("StereoKeypoints: descriptors for one image only")
        if self.left_desc is not None:
            self.left_desc = np.asarray(self.left_desc, np.float32).reshape(len(self.left), -1)
            self.right_desc = np.asarray(self.right_desc, np.float32).reshape(len(self.right), -1)
            if self.left_desc.shape[1] != self.right_desc.shape[1]:
                raise ValueError(f"StereoKeypoints: left descriptors have {self.left_desc.shape[1]} values, "
                                 f"right ones {self.right_desc.shape[1]}")

    @classmethod
    def from_detections(cls, left, right, disparity: np.ndarray | None = None,
                        disp_radius_px: int = 2, images: tuple[np.ndarray, np.ndarray] | None = None,
                        desc_size: float = 0.0, desc_grid: int = 11) -> StereoKeypoints:
        """From the left and right :class:`seedmap.records.Detections` of a view; with the view's
        SGBM ``disparity`` map (px, NaN = invalid) also the surface disparity at every left keypoint
        (:func:`keypoint_disparity`, for the ``mv_surface_tol`` check); with the rectified ``images``
        (left, right) and ``desc_size`` > 0 also every keypoint's appearance descriptor
        (:func:`context_descriptors`, half-width ``desc_size`` x the view's median left detection size)."""
        ld = None if disparity is None else keypoint_disparity(disparity, left.keypoints, disp_radius_px)
        kp = cls(left.keypoints, right.keypoints, 0.5 * (left.ellipses[:, 2] + left.ellipses[:, 3]), ld)
        if images is not None and desc_size > 0:
            kp.describe(images[0], images[1], desc_size, desc_grid)
        return kp

    def describe(self, left_image: np.ndarray, right_image: np.ndarray, desc_size: float, grid: int = 11) -> None:
        """Sets ``left_desc`` / ``right_desc`` (:func:`context_descriptors`) from the view's rectified
        images; the patch half-width is ``desc_size`` x the view's median left detection size (7 px when
        the view has no left detection)."""
        r = desc_size * (float(np.median(self.left_size)) if len(self.left_size) else 7.0)
        self.left_desc = context_descriptors(left_image, self.left, r, grid)
        self.right_desc = context_descriptors(right_image, self.right, r, grid)


def context_descriptors(image: np.ndarray, uv: np.ndarray, radius_px: float, grid: int = 11) -> np.ndarray:
    """Appearance of the neighbourhood of every keypoint ``uv`` (N, 2) px: the (2 radius)^2 px square
    around it, box-averaged to ``grid`` x ``grid`` cells per colour channel (bilinear samples of the
    box-filtered image, so sub-pixel keypoints are honoured), made zero-mean and unit-norm -> (N,
    grid^2 x channels) float32; the dot product of two is their normalised cross-correlation. A seed's
    context (its neighbours, the rachis behind it) tells a true left/right pair from a neighbour on the
    same row, which the seed alone does not (see step 1 of the module docstring)."""
    import cv2

    uv = np.asarray(uv, np.float32).reshape(-1, 2)
    img = np.asarray(image)
    if img.ndim == 2:
        img = img[:, :, None]
    C = img.shape[2]
    if len(uv) == 0:
        return np.zeros((0, grid * grid * C), np.float32)
    step = 2.0 * float(radius_px) / grid
    k = max(1, int(round(step)))
    sm = cv2.blur(img.astype(np.float32), (k, k)) if k > 1 else img.astype(np.float32)
    sm = sm.reshape(img.shape[0], img.shape[1], C)
    off = (np.arange(grid, dtype=np.float32) - 0.5 * (grid - 1)) * step
    mx = (uv[:, 0, None, None] + off[None, None, :]).astype(np.float32)
    my = (uv[:, 1, None, None] + off[None, :, None]).astype(np.float32)
    mx, my = np.broadcast_to(mx, (len(uv), grid, grid)), np.broadcast_to(my, (len(uv), grid, grid))
    # remap takes at most 32767 rows: sample the (N * grid, grid) map in chunks
    out = np.empty((len(uv) * grid, grid, C), np.float32)
    mx2, my2 = np.ascontiguousarray(mx.reshape(-1, grid)), np.ascontiguousarray(my.reshape(-1, grid))
    for a in range(0, len(mx2), 30000):
        smp = cv2.remap(sm, mx2[a:a + 30000], my2[a:a + 30000], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
        out[a:a + 30000] = smp.reshape(len(smp), grid, C)
    d = out.reshape(len(uv), -1)
    d -= d.mean(axis=1, keepdims=True)
    n = np.linalg.norm(d, axis=1, keepdims=True)
    return np.where(n > 1e-6, d / np.maximum(n, 1e-6), 0.0).astype(np.float32)


def keypoint_disparity(disparity: np.ndarray, uv: np.ndarray, radius_px: int = 2) -> np.ndarray:
    """Median of the valid SGBM disparities (px) in the (2r+1)^2 window around each keypoint ``uv``
    (N, 2) px; NaN where fewer than a quarter of the window is valid (SGBM often has no depth on a
    seed-sized patch: no evidence then, rather than a wrong one)."""
    uv = np.asarray(uv, float).reshape(-1, 2)
    if len(uv) == 0:
        return np.zeros(0)
    H, W = disparity.shape[:2]
    r = int(radius_px)
    off = np.arange(-r, r + 1)
    u = np.clip(np.round(uv[:, 0]).astype(np.int64)[:, None, None] + off[None, None, :], 0, W - 1)
    v = np.clip(np.round(uv[:, 1]).astype(np.int64)[:, None, None] + off[None, :, None], 0, H - 1)
    patch = np.asarray(disparity, float)[v, u].reshape(len(uv), -1)
    valid = np.isfinite(patch)
    out = np.full(len(uv), np.nan)
    ok = valid.sum(axis=1) >= max(1, patch.shape[1] // 4)
    if ok.any():
        out[ok] = np.nanmedian(patch[ok], axis=1)
    return out


@dataclass
class MultiViewDetail:
    """Intermediate results of :func:`count_multiview` (diagnostics and tests): every stereo match
    (view, left index, right index, support) and the track it ended in (index into ``xyz``,
    -1 = dropped for its reprojection error)."""

    view: np.ndarray
    left: np.ndarray
    right: np.ndarray
    support: np.ndarray
    track: np.ndarray
    xyz: np.ndarray  # (T, 3) triangulated point of every track (m, world)
    track_views: np.ndarray  # (T,) distinct views of every track


def _project_world(calib, T_cam_world: np.ndarray, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World points (N, 3) m -> left pixels (N, 2) and right columns (N,) of one view."""
    return calib.project(transform_points(T_cam_world, X))


def _stereo_candidates(L: np.ndarray, R: np.ndarray, d_lo: float, d_hi: float, dv: float) -> np.ndarray:
    """(P, 2) index pairs (left, right) on the same row (within ``dv`` px) with a disparity in
    [``d_lo``, ``d_hi``] px: one Chebyshev-ball query, rows scaled so both tolerances are one radius."""
    if len(L) == 0 or len(R) == 0:
        return np.zeros((0, 2), np.int64)
    half = 0.5 * (d_hi - d_lo)
    s = half / dv
    a = np.column_stack([L[:, 0] - 0.5 * (d_hi + d_lo), L[:, 1] * s])
    b = np.column_stack([R[:, 0], R[:, 1] * s])
    m = cKDTree(a).sparse_distance_matrix(cKDTree(b), half, p=np.inf, output_type="ndarray")
    if len(m) == 0:
        return np.zeros((0, 2), np.int64)
    return np.column_stack([m["i"], m["j"]]).astype(np.int64)


def _nearest(tree: cKDTree | None, uv: np.ndarray, r: float) -> tuple[np.ndarray, np.ndarray]:
    """Distance (inf = none within ``r`` px) and index (-1) of the nearest keypoint of ``tree``."""
    d = np.full(len(uv), np.inf)
    j = np.full(len(uv), -1, np.int64)
    ok = np.all(np.isfinite(uv), axis=1)
    if tree is not None and tree.n and ok.any():
        dd, jj = tree.query(uv[ok], distance_upper_bound=r)
        hit = np.isfinite(dd)
        idx = np.flatnonzero(ok)[hit]
        d[idx], j[idx] = dd[hit], jj[hit]
    return d, j


def _neighbour_views(k: int, V: int, max_off: int, circular: bool, both_sides: bool) -> list[tuple[int, int]]:
    """(lag, view) of the views up to ``max_off`` steps after (and before, ``both_sides``) view k."""
    out = []
    for off in range(1, max_off + 1):
        for m in ((k + off, k - off) if both_sides else (k + off,)):
            if circular:
                m %= V
            if 0 <= m < V and m != k and (off, m) not in out and all(m != x for _, x in out):
                out.append((off, m))
    return out


def _merge_components(xy: np.ndarray, r: float, pair_r: np.ndarray | None = None
                      ) -> tuple[np.ndarray, np.ndarray]:
    """Connected components of points (px) closer than ``r``: (label per point, mean position per label).
    ``pair_r`` (one radius per point, px): a pair is joined only when closer than the smaller radius of
    its two points as well (``r`` is then the largest radius considered)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    n = len(xy)
    if n == 0:
        return np.zeros(0, np.int64), np.zeros((0, 2))
    pr = cKDTree(xy).query_pairs(r, output_type="ndarray")
    if pair_r is not None and len(pr):
        d = np.linalg.norm(xy[pr[:, 0]] - xy[pr[:, 1]], axis=1)
        pr = pr[d < np.minimum(pair_r[pr[:, 0]], pair_r[pr[:, 1]])]
    g = coo_matrix((np.ones(len(pr)), (pr[:, 0], pr[:, 1])), shape=(n, n)) if len(pr) else coo_matrix((n, n))
    _, lab = connected_components(g, directed=False)
    cnt = np.bincount(lab)
    mean = np.column_stack([np.bincount(lab, weights=xy[:, i]) / cnt for i in range(2)])
    return lab.astype(np.int64), mean


def merge_close_keypoints(kp: StereoKeypoints, r_px: float, size_factor: float = 0.0
                          ) -> tuple[StereoKeypoints, np.ndarray]:
    """Joins keypoints of one image closer than ``r_px`` (px; chains join too) into their mean --
    duplicate detections of one seed; touching seeds are about one seed diameter apart, so ``r_px``
    must stay well below the seed size in pixels. ``size_factor`` > 0 scales the radius with the
    detections' own size instead: two left keypoints are joined when closer than ``size_factor`` x
    the smaller of their two sizes (``left_size``, px), two right keypoints (no sizes of their own)
    when closer than ``size_factor`` x the image's median left size; ``r_px`` > 0 then caps the radius.
    Left sizes and SGBM disparities are averaged (NaN-aware). Returns the merged keypoints and the
    merged index of every original left keypoint."""
    if size_factor > 0:
        rl = size_factor * kp.left_size
        rr = size_factor * float(np.median(kp.left_size)) if len(kp.left_size) else 0.0
        if r_px > 0:
            rl, rr = np.minimum(rl, r_px), min(rr, r_px)
        rmax = float(rl.max()) if len(rl) else 0.0
        lab, left = _merge_components(kp.left, max(rmax, 1e-9), rl)
        lab_r, right = _merge_components(kp.right, max(rr, 1e-9))
    else:
        lab, left = _merge_components(kp.left, r_px)
        lab_r, right = _merge_components(kp.right, r_px)
    n = len(left)
    cnt = np.maximum(np.bincount(lab, minlength=n), 1)
    size = np.bincount(lab, weights=kp.left_size, minlength=n) / cnt
    disp = None
    if kp.left_disp is not None:
        ok = np.isfinite(kp.left_disp)
        k = np.bincount(lab[ok], minlength=n)
        with np.errstate(invalid="ignore", divide="ignore"):
            disp = np.where(k > 0, np.bincount(lab[ok], weights=kp.left_disp[ok], minlength=n) / k, np.nan)
    dl = dr = None
    if kp.left_desc is not None:
        dl, dr = _mean_desc(kp.left_desc, lab, n), _mean_desc(kp.right_desc, lab_r, len(right))
    return StereoKeypoints(left, right, size, disp, dl, dr), lab


def _mean_desc(d: np.ndarray, lab: np.ndarray, n: int) -> np.ndarray:
    """Per-label mean of unit descriptors ``d``, re-normalised (merged keypoints)."""
    m = np.zeros((n, d.shape[1]), np.float32)
    np.add.at(m, lab, d)
    nm = np.linalg.norm(m, axis=1, keepdims=True)
    return (m / np.maximum(nm, 1e-6)).astype(np.float32)


def _surface_consistent(d_match: np.ndarray, d_sgbm: np.ndarray, calib, tol_behind: float,
                        tol_front: float) -> np.ndarray:
    """Surface-depth check of stereo match candidates: keep those whose depth (from the keypoint
    disparity ``d_match``, px) lies at most ``tol_behind`` (m) behind and ``tol_front`` (m) in front
    of the SGBM surface depth at the left keypoint (``d_sgbm``, px); candidates without a valid SGBM
    disparity are kept (no evidence)."""
    fb = calib.fx * calib.baseline
    with np.errstate(divide="ignore", invalid="ignore"):
        dz = fb / d_match - fb / d_sgbm  # > 0: the match lies behind the visible surface
    return ~(np.isfinite(d_sgbm) & (d_sgbm > 0) & ~((dz <= tol_behind) & (dz >= -tol_front)))


def _stereo_matches(views: list[StereoKeypoints | None], poses: np.ndarray, Tcw: np.ndarray, calib, cfg: CountConfig,
                    min_support: float) -> list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]:
    """Step 1 (module docstring): per view, one-to-one left/right matches verified by the
    neighbouring views (support >= ``min_support``) -> (left idx, right idx, world point (m), support) per view."""
    from scipy.optimize import linear_sum_assignment

    trees = _keypoint_trees(views)
    d_lo = calib.fx * calib.baseline / cfg.mv_max_depth
    d_hi = calib.fx * calib.baseline / cfg.mv_min_depth
    empty = (np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros(0))
    out = []
    for k, kp in enumerate(views):
        if kp is None:
            out.append(empty)
            continue
        c = _stereo_candidates(kp.left, kp.right, d_lo, d_hi, cfg.mv_stereo_dv_px)
        if len(c) and cfg.mv_surface_tol > 0 and kp.left_disp is not None:
            c = c[_surface_consistent(kp.left[c[:, 0], 0] - kp.right[c[:, 1], 0], kp.left_disp[c[:, 0]],
                                      calib, cfg.mv_surface_tol, cfg.mv_surface_tol if cfg.mv_surface_front_tol
                                      is None else cfg.mv_surface_front_tol)]
        if len(c) == 0:
            out.append(empty)
            continue
        Xw = transform_points(poses[k], calib.triangulate(kp.left[c[:, 0]], kp.right[c[:, 1], 0]))
        support = _view_support(k, Xw, views, trees, Tcw, calib, cfg)
        ok = support >= min_support
        c, Xw, support = c[ok], Xw[ok], support[ok]
        if len(c) == 0:
            out.append(empty)
            continue
        w = support
        if cfg.mv_appearance_weight > 0 and kp.left_desc is not None:
            # appearance: normalised cross-correlation of the two keypoints' context patches
            ncc = np.einsum("ij,ij->i", kp.left_desc[c[:, 0]], kp.right_desc[c[:, 1]])
            ok = ncc >= cfg.mv_appearance_min
            c, Xw, support, ncc = c[ok], Xw[ok], support[ok], ncc[ok]
            if len(c) == 0:
                out.append(empty)
                continue
            w = support * np.exp(cfg.mv_appearance_weight * (ncc - 1.0))
        if cfg.mv_row_sigma_px > 0:
            # rank candidates by their epipolar (row) residual too: a true pair's rows differ by ~1 px,
            # a wrong partner anywhere within the (wide) row tolerance
            dv = kp.left[c[:, 0], 1] - kp.right[c[:, 1], 1]
            w = w * np.exp(-0.5 * (dv / cfg.mv_row_sigma_px) ** 2)
        lab_l, lab_r = c[:, 0], c[:, 1]
        if cfg.mv_dup_size > 0:
            # left keypoints closer than mv_dup_size x their detection size look like one seed: such a
            # group takes part in the assignment as ONE row, with its best candidate per right keypoint
            lab_l = _dup_groups(kp, cfg.mv_dup_size)[c[:, 0]]
            o = np.argsort(-w, kind="stable")
            _, first = np.unique(lab_l[o] * (int(lab_r.max()) + 1) + lab_r[o], return_index=True)
            best = o[first]
            c, Xw, support, w, lab_l, lab_r = c[best], Xw[best], support[best], w[best], lab_l[best], lab_r[best]
        # one-to-one, maximal total support: assignment on the candidate rows/columns only
        rows, ri = np.unique(lab_l, return_inverse=True)
        cols, ci = np.unique(lab_r, return_inverse=True)
        gain = np.zeros((len(rows), len(cols)))
        gain[ri, ci] = w
        a, b = linear_sum_assignment(gain, maximize=True)
        pick = np.full((len(rows), len(cols)), -1, np.int64)
        pick[ri, ci] = np.arange(len(c))
        q = pick[a, b]
        q = np.sort(q[q >= 0])
        out.append((c[q, 0], c[q, 1], Xw[q], support[q]))
    return out


def _dup_groups(kp: StereoKeypoints, size_factor: float) -> np.ndarray:
    """Group label of every left keypoint of one view: keypoints closer than ``size_factor`` x the
    smaller of their two detection sizes (px) look like one seed (chains join)."""
    rl = size_factor * kp.left_size
    lab, _ = _merge_components(kp.left, max(float(rl.max()) if len(rl) else 0.0, 1e-9), rl)
    return lab


def _keypoint_trees(views: list[StereoKeypoints | None]) -> list[tuple[cKDTree | None, cKDTree | None]]:
    """(left, right) keypoint KD-trees (px) of every view (None for skipped views)."""
    return [(cKDTree(v.left), cKDTree(v.right)) if v is not None else (None, None) for v in views]


def view_spacing_deg(poses: np.ndarray) -> float:
    """Median angle (degrees) between the optical axes of consecutive views (15 for the default 24-view circle)."""
    z = np.asarray(poses, float).reshape(-1, 4, 4)[:, :3, 2]
    if len(z) < 2:
        return float("nan")
    c = np.clip(np.einsum("ij,ij->i", z[:-1], z[1:]), -1.0, 1.0)
    return float(np.degrees(np.median(np.arccos(c))))


def support_shift(poses: np.ndarray, cfg: CountConfig) -> float:
    """What a scan with views closer together than ``mv_support_ref_deg`` adds to the stereo matches' minimum
    supports (``mv_min_support`` and ``mv_relink_min_support``): ``mv_support_density_gain`` x (ref / spacing - 1)
    when the scan is >= 5 % denser, else 0 (module docstring, session 13)."""
    if cfg.mv_support_density_gain <= 0 or cfg.mv_support_ref_deg <= 0:
        return 0.0
    sp = view_spacing_deg(poses)
    if not np.isfinite(sp) or sp <= 0:
        return 0.0
    r = cfg.mv_support_ref_deg / sp
    return float(cfg.mv_support_density_gain * (r - 1.0)) if r >= 1.05 else 0.0


def _view_support(k: int, Xw: np.ndarray, views: list[StereoKeypoints | None], trees: list, Tcw: np.ndarray,
                  calib, cfg: CountConfig) -> np.ndarray:
    """Support (step 1, module docstring) of world points ``Xw`` (N, 3) m seen in view ``k``: sum over
    the left and right images of the ``mv_verify_views`` views on each side of exp(-e^2 / 2 sigma^2),
    e = distance (px) of the projection to the nearest detection there."""
    sig = cfg.mv_support_sigma_px
    support = np.zeros(len(Xw))
    for _, m in _neighbour_views(k, len(views), cfg.mv_verify_views, cfg.circular, both_sides=True):
        if views[m] is None:
            continue
        uvl, ur = _project_world(calib, Tcw[m], Xw)
        dl, _ = _nearest(trees[m][0], uvl, 3 * sig)
        dr, _ = _nearest(trees[m][1], np.column_stack([ur, uvl[:, 1]]), 3 * sig)
        support += np.exp(-0.5 * (dl / sig) ** 2) + np.exp(-0.5 * (dr / sig) ** 2)
    return support


def _triangulate_tracks(roots: np.ndarray, alive: np.ndarray, view: np.ndarray, uvL: np.ndarray, uR: np.ndarray,
                        poses: np.ndarray, Tcw: np.ndarray, calib, by_view: dict,
                        cfg: CountConfig) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Step 3 (module docstring): triangulates every track (observations sharing a ``root``) from the
    rays of all its left and right keypoints and drops observations reprojecting farther than
    ``mv_max_reproj_px`` (three rounds). Dropped and dead (``~alive``) observations become singleton
    groups. Returns (kept mask, group per observation, world point (m) per group)."""
    n = len(view)
    cL, dL = _rays(calib, poses, view, uvL[:, 0], uvL[:, 1], right=False)
    cR, dR = _rays(calib, poses, view, uR, uvL[:, 1], right=True)
    C2, D2 = np.concatenate([cL, cR]), np.concatenate([dL, dR])
    keep = alive.copy()
    for _ in range(cfg.mv_reproj_rounds):
        _, comp = np.unique(np.where(keep, roots, -1 - np.arange(n)), return_inverse=True)
        G = int(comp.max()) + 1
        Xg = triangulate_rays(np.concatenate([comp, comp]), G, C2, D2)
        err = np.full(n, np.inf)
        for k, idx in by_view.items():
            pl, pr = _project_world(calib, Tcw[k], Xg[comp[idx]])
            err[idx] = np.maximum(np.linalg.norm(pl - uvL[idx], axis=1), np.abs(pr - uR[idx]))
        bad = keep & ~(err <= cfg.mv_max_reproj_px)
        if not bad.any():
            break
        if cfg.mv_drop_worst_only:
            # one wrong observation pulls its track's point and makes the good ones look bad too:
            # drop only the worst of each track per round, then re-triangulate
            worst = np.full(G, -np.inf)
            np.maximum.at(worst, comp[keep], np.where(np.isfinite(err[keep]), err[keep], 1e9))
            bad &= np.where(np.isfinite(err), err, 1e9) >= worst[comp]
        keep &= ~bad
    _, comp = np.unique(np.where(keep, roots, -1 - np.arange(n)), return_inverse=True)
    Xg = triangulate_rays(np.concatenate([comp, comp]), int(comp.max()) + 1, C2, D2)
    return keep, comp, Xg


def _grow_tracks(views: list[StereoKeypoints | None], trees: list, comp: np.ndarray, keep: np.ndarray,
                 alive: np.ndarray, Xg: np.ndarray, view: np.ndarray, il: np.ndarray, ir: np.ndarray,
                 Tcw: np.ndarray, calib, cfg: CountConfig):
    """Step 3b (module docstring): every track seen from >= ``min_observations`` views projects its
    point into the views up to ``mv_grow_views`` around its own that it lacks; where a left AND a
    right keypoint (same row) lie within ``mv_grow_px`` of the projection it claims that pair --
    taking it from its current stereo match only when that match belongs to a track with fewer views
    (a ghost match built from this seed's keypoint, or a fragment of it). Tracks with more views
    choose first, nearest first. Returns None when nothing was claimed, else the new observations
    (view, left idx, right idx, claiming group) and the indices of the observations they replace."""
    V = len(views)
    live = keep & alive
    G = int(comp.max()) + 1
    vm = np.zeros((G, V), bool)
    vm[comp[live], view[live]] = True
    nv = vm.sum(axis=1)
    grower = (nv >= cfg.min_observations) & np.all(np.isfinite(Xg), axis=1)
    if not grower.any():
        return None
    lown = [np.full(len(v.left), -1, np.int64) if v is not None else None for v in views]
    rown = [np.full(len(v.right), -1, np.int64) if v is not None else None for v in views]
    for o in np.flatnonzero(alive).tolist():
        lown[view[o]][il[o]] = o
        rown[view[o]][ir[o]] = o
    onv = np.where(live, nv[comp], 0)  # views of the track each observation is in (0 = dropped)
    w = cfg.mv_grow_views
    cand = []
    for m in range(V):
        if views[m] is None:
            continue
        before = np.zeros(G, bool)
        after = np.zeros(G, bool)
        for off in range(1, w + 1):
            for k, side in ((m - off, before), (m + off, after)):
                if cfg.circular:
                    k %= V
                if 0 <= k < V:
                    side |= vm[:, k]
        # gap filling only (seen on both sides of view m): beyond the end of its arc a seed turns away
        # and its foreshortened neighbour lands where it would project
        near = (before & after) if cfg.mv_grow_fill_only else (before | after)
        g = np.flatnonzero(grower & near & ~vm[:, m])
        if len(g) == 0:
            continue
        pc = transform_points(Tcw[m], Xg[g])
        front = pc[:, 2] > 0
        g, pc = g[front], pc[front]
        pl, pr = calib.project(pc)
        dl, i = _nearest(trees[m][0], pl, cfg.mv_grow_px)
        dr, j = _nearest(trees[m][1], np.column_stack([pr, pl[:, 1]]), cfg.mv_grow_px)
        hit = (i >= 0) & (j >= 0)
        if cfg.mv_grow_unique_px > 0 and hit.any():
            # unambiguous only: near the silhouette (grazing view) neighbouring seeds crowd together
            # in the image and a hidden seed's projection lands on a neighbour
            d2, _ = trees[m][0].query(pl[hit], k=2)
            hit[np.flatnonzero(hit)[d2[:, 1] < cfg.mv_grow_unique_px]] = False
        cand.append(np.column_stack([-nv[g[hit]], dl[hit] + dr[hit], g[hit], np.full(hit.sum(), m), i[hit], j[hit]]))
    if not cand:
        return None
    C = np.concatenate(cand)
    C = C[np.lexsort((C[:, 1], C[:, 0]))]
    taken_l: set = set()
    taken_r: set = set()
    out, dead = [], []
    for _, _, g, m, i, j in C.tolist():
        g, m, i, j = int(g), int(m), int(i), int(j)
        if (m, i) in taken_l or (m, j) in taken_r:
            continue
        oi, oj = int(lown[m][i]), int(rown[m][j])
        if (oi >= 0 and onv[oi] >= nv[g]) or (oj >= 0 and onv[oj] >= nv[g]):
            continue
        taken_l.add((m, i))
        taken_r.add((m, j))
        dead += [o for o in (oi, oj) if o >= 0]
        out.append((m, i, j, g))
    if not out:
        return None
    o = np.array(out, np.int64)
    return o[:, 0], o[:, 1], o[:, 2], o[:, 3], np.unique(np.array(dead, np.int64))


def _rays(calib, poses: np.ndarray, view: np.ndarray, u: np.ndarray, v: np.ndarray,
          right: bool) -> tuple[np.ndarray, np.ndarray]:
    """World camera centres (N, 3) and unit ray directions (N, 3) of pixels (u, v) of the left or
    right camera of each observation's view."""
    R = poses[view][:, :3, :3]
    c = poses[view][:, :3, 3] + (R[:, :, 0] * calib.baseline if right else 0.0)
    d = np.einsum("nij,nj->ni", R, np.column_stack([(u - calib.cx) / calib.fx, (v - calib.cy) / calib.fy,
                                                     np.ones(len(u))]))
    return c, d / np.linalg.norm(d, axis=1, keepdims=True)


def triangulate_rays(group: np.ndarray, n_groups: int, centres: np.ndarray, dirs: np.ndarray) -> np.ndarray:
    """Linear least-squares triangulation: for each group the point (m) minimising the summed
    squared distances to its rays (camera centre ``centres``, unit direction ``dirs``), i.e. the
    solution of sum (I - d d^T)(X - c) = 0. NaN for groups whose rays are (nearly) parallel."""
    P = np.eye(3)[None] - dirs[:, :, None] * dirs[:, None, :]
    A = np.zeros((n_groups, 3, 3))
    b = np.zeros((n_groups, 3))
    np.add.at(A, group, P)
    np.add.at(b, group, np.einsum("nij,nj->ni", P, centres))
    X = np.full((n_groups, 3), np.nan)
    ok = np.linalg.cond(A) < 1e8 if n_groups else np.zeros(0, bool)
    if ok.any():
        X[ok] = np.linalg.solve(A[ok], b[ok][:, :, None])[:, :, 0]
    return X


def _link_edges(by_view: dict, trees: dict, X: np.ndarray, uvL: np.ndarray, uR: np.ndarray, Tcw: np.ndarray,
                calib, V: int, max_lag: int, link_px: float, link_px_per_lag: float,
                circular: bool, rays: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None = None,
                search: float = 2.0) -> np.ndarray:
    """Step 2 (module docstring): symmetric reprojection links between the stereo matches of views
    up to ``max_lag`` apart, tolerance ``link_px`` (+ ``link_px_per_lag`` per view of lag beyond the
    first) px; each match of the later view keeps its cheapest partner. Rows (lag, cost px, a, b),
    nearest views first, cheapest first.

    With ``rays`` (left centres, left directions, right centres, right directions of every match)
    the test is joint instead: the nearest match b within ``search`` x the tolerance of a's
    projection is linked when the point triangulated from the four rays of a and b reprojects within
    the tolerance into all four images -- the depth error of one biased stereo match (a partly
    hidden seed's visible centre differs between left and right) is then shared by both views."""
    edges = []
    for k, A in by_view.items():
        for lag, m in _neighbour_views(k, V, max_lag, circular, both_sides=False):
            if m not in by_view:
                continue
            lnk = link_px + link_px_per_lag * (lag - 1)  # relative pose errors grow with lag
            pl, pr = _project_world(calib, Tcw[m], X[A])
            dl, j = _nearest(trees[m], pl, lnk if rays is None else search * lnk)
            hit = np.flatnonzero(j >= 0)
            a, b = A[hit], by_view[m][j[hit]]
            if rays is None:
                e_r = np.abs(pr[hit] - uR[b])
                ql, qr = _project_world(calib, Tcw[k], X[b])
                e_bl = np.linalg.norm(ql - uvL[a], axis=1)
                e_br = np.abs(qr - uR[a])
                ok = (e_r <= lnk) & (e_bl <= lnk) & (e_br <= lnk)
                cost = (dl[hit][ok] + e_r[ok] + e_bl[ok] + e_br[ok]) / 4.0
            else:
                cl, dl_, cr, dr_ = rays
                P = len(a)
                grp = np.tile(np.arange(P), 4)
                Xj = triangulate_rays(grp, P, np.concatenate([cl[a], cr[a], cl[b], cr[b]]),
                                      np.concatenate([dl_[a], dr_[a], dl_[b], dr_[b]]))
                e = np.zeros((P, 4))
                for col, (idx, kk) in enumerate(((a, k), (b, m))):
                    ql, qr = _project_world(calib, Tcw[kk], Xj)
                    e[:, 2 * col] = np.linalg.norm(ql - uvL[idx], axis=1)
                    e[:, 2 * col + 1] = np.abs(qr - uR[idx])
                e[~np.isfinite(e)] = np.inf
                ok = np.all(e <= lnk, axis=1)
                cost = e[ok].mean(axis=1)
            a, b = a[ok], b[ok]
            o = np.lexsort((cost, b))  # each b keeps its cheapest a
            first = np.ones(len(o), bool)
            first[1:] = b[o][1:] != b[o][:-1]
            o = o[first]
            edges.append(np.column_stack([np.full(len(o), lag), cost[o], a[o], b[o]]))
    E = np.concatenate(edges) if edges else np.zeros((0, 4))
    return E[np.lexsort((E[:, 1], E[:, 0]))]


def size_scale(views: list[StereoKeypoints | None], cfg: CountConfig) -> float:
    """Scale factor of the pixel tolerances (step 0a, module docstring): (median left detection size
    of the scan, px / ``mv_scale_ref_px``) ** ``mv_scale_power``, clipped to [``mv_scale_min``,
    ``mv_scale_max``]; 1 when scaling is off or there are no detections."""
    sizes = [v.left_size for v in views if v is not None and len(v.left_size)]
    if cfg.mv_scale_ref_px <= 0 or not sizes:
        return 1.0
    med = float(np.median(np.concatenate(sizes)))
    return float(np.clip((med / cfg.mv_scale_ref_px) ** cfg.mv_scale_power, cfg.mv_scale_min, cfg.mv_scale_max))


def scaled_tolerances(views: list[StereoKeypoints | None], cfg: CountConfig) -> CountConfig:
    """``cfg`` with its ``mv_scale_keys`` pixel tolerances multiplied by :func:`size_scale` and the
    scaling switched off (applied once)."""
    from seedmap.errors import ConfigError

    bad = [k for k in cfg.mv_scale_keys if not isinstance(getattr(cfg, k, None), float)]
    if bad:
        raise ConfigError(f"count.mv_scale_keys: {', '.join(bad)} is not a pixel tolerance of CountConfig")
    f = size_scale(views, cfg)
    upd = {k: getattr(cfg, k) * f for k in cfg.mv_scale_keys}
    upd["mv_scale_ref_px"] = 0.0
    return cfg.model_copy(update=upd)


def count_multiview(views: list[StereoKeypoints | None], poses: np.ndarray, calib, cfg: CountConfig,
                    detail: bool = False) -> SeedCount | tuple[SeedCount, MultiViewDetail]:
    """The ``multiview`` method (module docstring): count seeds from the 2D detections ``views``
    (one :class:`StereoKeypoints` per view, None = skipped view), the registered camera poses
    ``poses`` (V, 4, 4) T_world_cam of the left cameras (m) and the rectified ``calib``.

    Returns a :class:`SeedCount` whose ``assignment`` indexes the LEFT detections of all views
    concatenated in view order (-1 = not counted); ``spread`` is the RMS distance (m) of a seed's
    per-view stereo points to its triangulated position. ``detail=True`` also returns the stereo
    matches and tracks (:class:`MultiViewDetail`)."""
    poses = np.asarray(poses, float).reshape(-1, 4, 4)
    V = len(views)
    if len(poses) != V:
        raise ValueError(f"{len(poses)} poses for {V} views")
    sp = view_spacing_deg(poses)
    if cfg.mv_support_ref_deg > 0 and np.isfinite(sp) and sp > 1.05 * cfg.mv_support_ref_deg:
        import warnings

        warnings.warn(f"the views are {sp:.1f} deg apart; the multiview counter's settings are for "
                      f"{cfg.mv_support_ref_deg:g} deg (24 views) and under-counted simulated 12-view scans by about "
                      "13 %", stacklevel=2)
    if cfg.mv_scale_ref_px > 0:
        # step 0a: pixel tolerances scaled with the seeds' median image size (module docstring)
        cfg = scaled_tolerances(views, cfg)
    if cfg.mv_merge_px > 0 or cfg.mv_merge_size > 0:
        # step 0: duplicate detections of one seed (a detector firing twice on it) -> one keypoint
        merged = [merge_close_keypoints(v, cfg.mv_merge_px, cfg.mv_merge_size) if v is not None
                  else (None, np.zeros(0, np.int64)) for v in views]
        res = count_multiview([m[0] for m in merged], poses, calib,
                              cfg.model_copy(update={"mv_merge_px": 0.0, "mv_merge_size": 0.0}), detail=detail)
        cnt = res[0] if detail else res
        n_m = np.array([len(m[0].left) if m[0] is not None else 0 for m in merged], np.int64)
        off_m = np.concatenate([[0], np.cumsum(n_m)])
        cnt.assignment = np.concatenate([cnt.assignment[off_m[k] + m[1]] for k, m in enumerate(merged)]
                                        ) if V else np.zeros(0, np.int64)
        return res
    from seedmap.geometry import invert

    Tcw = invert(poses)
    n_left = np.array([len(v.left) if v is not None else 0 for v in views], np.int64)
    offset = np.concatenate([[0], np.cumsum(n_left)])
    shift = support_shift(poses, cfg)  # (scans denser than the 24-view circle, module docstring)
    st = _stereo_matches(views, poses, Tcw, calib, cfg, cfg.mv_min_support + shift)
    view = np.concatenate([np.full(len(s[0]), k, np.int64) for k, s in enumerate(st)]) if V else np.zeros(0, np.int64)
    il = np.concatenate([s[0] for s in st]) if V else np.zeros(0, np.int64)
    ir = np.concatenate([s[1] for s in st]) if V else np.zeros(0, np.int64)
    X = np.concatenate([s[2] for s in st]) if V else np.zeros((0, 3))
    support = np.concatenate([s[3] for s in st]) if V else np.zeros(0)
    n = len(view)
    empty = SeedCount(np.zeros((0, 3)), np.zeros(0), np.zeros(0, np.int64), np.full(offset[-1], -1, np.int64),
                      np.zeros(0))
    if n == 0:
        det = MultiViewDetail(view, il, ir, support, np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros(0, np.int64))
        return (empty, det) if detail else empty
    uvL = np.zeros((n, 2))
    uR = np.zeros(n)
    size = np.zeros(n)
    for k in np.unique(view):
        sel = view == k
        uvL[sel] = views[k].left[il[sel]]
        uR[sel] = views[k].right[ir[sel], 0]
        size[sel] = views[k].left_size[il[sel]]
    # step 2: symmetric reprojection links between views up to max_lag apart
    by_view = {int(k): np.flatnonzero(view == k) for k in np.unique(view)}
    trees = {k: cKDTree(uvL[i]) for k, i in by_view.items()}
    rays = None
    if cfg.mv_link_joint:
        rays = (*_rays(calib, poses, view, uvL[:, 0], uvL[:, 1], right=False),
                *_rays(calib, poses, view, uR, uvL[:, 1], right=True))
    E = _link_edges(by_view, trees, X, uvL, uR, Tcw, calib, V, cfg.max_lag, cfg.mv_link_px,
                    cfg.mv_link_px_per_lag, cfg.circular, rays, cfg.mv_link_search)
    uf = _CannotLinkUnionFind(view)
    for a, b in E[:, 2:].astype(np.int64).tolist():
        uf.union(a, b)
    if cfg.mv_relink_px > cfg.mv_link_px:
        # step 2b: second pass for observations still short of min_observations views: a wider
        # tolerance, only between well-supported stereo matches (module docstring)
        E2 = _link_edges(by_view, trees, X, uvL, uR, Tcw, calib, V, cfg.max_lag, cfg.mv_relink_px,
                         cfg.mv_link_px_per_lag, cfg.circular)
        strong = support >= cfg.mv_relink_min_support + shift
        for a, b in E2[:, 2:].astype(np.int64).tolist():
            if not (strong[a] and strong[b]):
                continue
            ra, rb = uf.find(a), uf.find(b)
            if (bin(uf.vmask[ra]).count("1") < cfg.min_observations
                    and bin(uf.vmask[rb]).count("1") < cfg.min_observations):
                uf.union(a, b)
    roots = np.array([uf.find(i) for i in range(n)])
    # step 3: triangulate every track from the rays of all its left and right keypoints
    alive = np.ones(n, bool)
    keep, comp, Xg = _triangulate_tracks(roots, alive, view, uvL, uR, poses, Tcw, calib, by_view, cfg)
    trees_kp = _keypoint_trees(views)
    if cfg.mv_grow_px > 0:
        # step 3b: tracks claim the detections their point projects onto in the views around them
        for _ in range(cfg.mv_grow_passes):
            grown = _grow_tracks(views, trees_kp, comp, keep, alive, Xg, view, il, ir, Tcw, calib, cfg)
            if grown is None:
                break
            new_view, new_il, new_ir, new_group, dead = grown
            alive[dead] = False
            o = np.argsort(new_view, kind="stable")  # view order (the supports below are computed per view)
            new_view, new_il, new_ir, new_group = new_view[o], new_il[o], new_ir[o], new_group[o]
            m = len(new_view)
            Xn = np.zeros((m, 3))
            for k in np.unique(new_view):
                sel = new_view == k
                Xn[sel] = transform_points(poses[k], calib.triangulate(views[k].left[new_il[sel]],
                                                                       views[k].right[new_ir[sel], 0]))
            # a grown observation joins the track of its claiming group (root = any member of it)
            member = np.full(int(comp.max()) + 1, -1, np.int64)
            member[comp[keep & alive]] = np.flatnonzero(keep & alive)
            new_root = roots[member[new_group]]
            view = np.concatenate([view, new_view])
            il = np.concatenate([il, new_il])
            ir = np.concatenate([ir, new_ir])
            X = np.concatenate([X, Xn])
            support = np.concatenate([support] + [_view_support(k, Xn[new_view == k], views, trees_kp, Tcw, calib, cfg)
                                                  for k in np.unique(new_view)])
            roots = np.concatenate([roots, new_root])
            alive = np.concatenate([alive, np.ones(m, bool)])
            uvL = np.concatenate([uvL, np.array([views[k].left[i] for k, i in zip(new_view, new_il)]).reshape(-1, 2)])
            uR = np.concatenate([uR, np.array([views[k].right[j, 0] for k, j in zip(new_view, new_ir)])])
            size = np.concatenate([size, np.array([views[k].left_size[i] for k, i in zip(new_view, new_il)])])
            n = len(view)
            by_view = {int(k): np.flatnonzero(view == k) for k in np.unique(view)}
            keep, comp, Xg = _triangulate_tracks(roots, alive, view, uvL, uR, poses, Tcw, calib, by_view, cfg)
    G = int(comp.max()) + 1
    cL, dL = _rays(calib, poses, view, uvL[:, 0], uvL[:, 1], right=False)
    cR, dR = _rays(calib, poses, view, uR, uvL[:, 1], right=True)
    C2, D2 = np.concatenate([cL, cR]), np.concatenate([dL, dR])
    # per-observation depth -> seed diameter (m)
    z = np.einsum("nj,nj->n", Tcw[view][:, 2, :3], X) + Tcw[view][:, 2, 3]
    diam = size * z / calib.fx
    # step 4: 3D de-duplication of counted tracks (fragments of one seed share no view)
    vm = [0] * G
    for k, g in zip(view[alive].tolist(), comp[alive].tolist()):
        vm[g] |= 1 << k
    nv = np.array([bin(m).count("1") for m in vm])
    counted = np.flatnonzero((nv >= cfg.min_observations) & np.all(np.isfinite(Xg), axis=1))
    uf2 = _CannotLinkUnionFind(np.zeros(G, np.int64))
    uf2.vmask = vm
    med_diam = float(np.median(diam))
    # the diameter a join radius is measured in: the scan's median seed, or (mv_dedupe_size="track")
    # the mean of the two tracks' own median diameters (large seeds among small ones)
    g_diam = None
    if cfg.mv_dedupe_size == "track":
        ok_d = alive & np.isfinite(diam)
        o = np.lexsort((diam[ok_d], comp[ok_d]))
        cg, dg = comp[ok_d][o], diam[ok_d][o]
        lo = np.searchsorted(cg, np.arange(G))
        hi = np.searchsorted(cg, np.arange(G), side="right")
        g_diam = np.full(G, med_diam)
        has = hi > lo
        g_diam[has] = 0.5 * (dg[(lo[has] + hi[has] - 1) // 2] + dg[(lo[has] + hi[has]) // 2])
    # join close tracks, nearest pairs first: first those that share no view (mv_dedupe), then
    # (step 4b) those closer than two seeds can be even when they share views — a detector firing
    # twice on one seed makes two consistent tracks through the same views (mv_dedupe_shared)
    for factor, force in ((cfg.mv_dedupe, False), (cfg.mv_dedupe_shared, True)):
        radius = factor * (med_diam if g_diam is None or not len(counted) else float(g_diam[counted].max()))
        if radius <= 0 or len(counted) < 2:
            continue
        pairs = cKDTree(Xg[counted]).query_pairs(radius, output_type="ndarray")
        if len(pairs):
            dd = np.linalg.norm(Xg[counted[pairs[:, 0]]] - Xg[counted[pairs[:, 1]]], axis=1)
            if g_diam is not None:
                ok_p = dd < factor * 0.5 * (g_diam[counted[pairs[:, 0]]] + g_diam[counted[pairs[:, 1]]])
                pairs, dd = pairs[ok_p], dd[ok_p]
            for p, q in counted[pairs[np.argsort(dd, kind="stable")]].tolist():
                uf2.union(p, q, force=force)
    _, track = np.unique(np.array([uf2.find(g) for g in range(G)])[comp], return_inverse=True)
    T = int(track.max()) + 1
    Xt = triangulate_rays(np.concatenate([track, track]), T, C2, D2)
    key = np.unique(track[alive] * V + view[alive])
    tv = np.bincount(key // V, minlength=T)
    ok_t = (tv >= cfg.min_observations) & np.all(np.isfinite(Xt), axis=1)
    new_index = np.full(T, -1, np.int64)
    new_index[ok_t] = np.arange(ok_t.sum())
    obs_seed = new_index[track]
    assignment = np.full(offset[-1], -1, np.int64)
    assignment[offset[view[alive]] + il[alive]] = obs_seed[alive]
    cnt_obs = np.bincount(track, minlength=T)
    d2 = np.sum((X - Xt[track]) ** 2, axis=1)
    spread = np.sqrt(np.bincount(track, weights=d2, minlength=T) / np.maximum(cnt_obs, 1))
    order = np.argsort(track, kind="stable")
    bounds = np.searchsorted(track[order], np.arange(T + 1))
    dmed = np.array([np.median(diam[order[bounds[t]:bounds[t + 1]]]) for t in np.flatnonzero(ok_t)])
    res = SeedCount(Xt[ok_t], dmed.reshape(-1), tv[ok_t], assignment, spread[ok_t])
    if detail:
        return res, MultiViewDetail(view, il, ir, support, np.where(keep & alive, track, -1), Xt, tv)
    return res
