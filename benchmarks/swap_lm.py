"""pytest plugin: run the existing solver tests with the LM core in place of the two former solvers.

    PYTHONPATH=$PWD:benchmarks python -m pytest -q -p swap_lm tests/test_solver.py tests/test_correction_calibration.py tests/test_pipeline.py

Replaces ``modules.refine.joint_refinement``/``JointRefinement`` (and the solver's import of it) and
``refine_centred_radial`` (in ``modules.centred_radial`` and the pipeline) by the wrappers of
``modules/calibration/refinement.py``, before the test modules import them.
"""

import ccs_kornia.modules.calibrator as c, ccs_kornia.modules.refine as r
from ccs_kornia.modules.calibration import refinement as n
c.joint_refinement = n.joint_refinement
r.joint_refinement = n.joint_refinement
r.JointRefinement = n.JointRefinement
import ccs_kornia.modules.centred_radial as cr, ccs_kornia.pipeline as p
cr.refine_centred_radial = n.refine_centred_radial
p.refine_centred_radial = n.refine_centred_radial
