"""The benchmark's sections, one module each (:data:`ccs_kornia.bench.config.SECTIONS`), with the parts that belong to
one section: the rendered half of the fisheye section (fisheye_rendered), the compute floors and stage profiles of the
speed section (floors), the held-out errors of the video section (heldout).
"""
