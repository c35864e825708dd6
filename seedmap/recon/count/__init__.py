"""Counting the seeds of one panicle from its arm scan (method in docs/method/counting.md).

``multiview`` (default, :func:`count_multiview`): the 2D detections of every view and the registered camera
poses -- stereo matches verified by the neighbouring views (:mod:`.stereo_match`), linked across views into
tracks, triangulated, grown and de-duplicated (:mod:`.tracks`, :mod:`.multiview`). ``density``
(:func:`count_density`, the paper's method): DBSCAN, density smoothing and local maxima on per-view 3D seed
centres.
"""

from seedmap.recon.count.density import count_density
from seedmap.recon.count.multiview import count_multiview, scaled_tolerances, size_scale
from seedmap.recon.count.records import MultiViewDetail, SeedCount, StereoKeypoints, keypoint_disparity
from seedmap.recon.count.stereo_match import support_shift, view_spacing_deg
from seedmap.recon.count.views import triangulate_rays

__all__ = ["MultiViewDetail", "SeedCount", "StereoKeypoints", "count_density", "count_multiview",
           "keypoint_disparity", "scaled_tolerances", "size_scale", "support_shift", "triangulate_rays",
           "view_spacing_deg"]
