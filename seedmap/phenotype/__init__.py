"""Phenotype table of a row pass: one row per panicle (position, height, size, volume, tilt, seed count).

:func:`~seedmap.phenotype.table.phenotype_result` reads a ``seedmap slam`` result folder and measures every
panicle of its seed map; :mod:`seedmap.phenotype.evaluate` scores the table against the simulator's ground
truth. Method: docs/method/phenotype.md.
"""
