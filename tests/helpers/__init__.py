"""Helpers shared by the tests: the CLI run in-process, small synthetic datasets, rerun recordings, the bad-input
matrix. ``tests/`` is on ``sys.path`` (pytest's rootdir import mode), so tests import ``helpers.<module>``."""
