"""seedmap: semantic stereo SLAM and panicle reconstruction with sorghum seeds as landmarks.

Importing this package never imports torch: the learned detectors live behind the optional
``seedmap[learned]`` extra and are imported lazily.
"""

__version__ = "0.8.3"  # the one place the version is written (pyproject.toml reads it)
