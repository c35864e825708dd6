"""Ground-truth stereo renderer: Open3D ray casting on the CPU, flash lighting, a sensor model.

``render_stereo`` renders a rectified pair with exact labels. The modules, in the order a frame uses them:
``scene`` (BVHs and the per-frame scene), ``culling`` (which pixels can see an object), ``shading``,
``shadows``, ``antialias``, ``sensor`` and ``labels``; ``stereo`` puts them together. How and why:
docs/method/simulator.md.
"""

from seedmap.sim.render.shading import REF_DISTANCE
from seedmap.sim.render.stereo import RenderedStereo, render_stereo, right_pose

__all__ = ["REF_DISTANCE", "RenderedStereo", "render_stereo", "right_pose"]
