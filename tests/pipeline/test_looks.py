from types import SimpleNamespace

import torch

from ccs_kornia.modules.detection.base import DetectionResult, Fallbacks
from ccs_kornia.pipeline.looks import (
    CALIBRATED,
    CORRECTED,
    FIRST,
    FIRST_PASSES,
    FORESHORTENED,
    LOOKS,
    Look,
    Tools,
    own_fallbacks,
    second_look_fallbacks,
)


def test_the_looks_in_order_and_what_they_need():
    assert LOOKS == (CORRECTED, CALIBRATED, FORESHORTENED)
    assert [look.needs_correction for look in LOOKS] == [True, False, False]
    assert [look.needs_camera for look in LOOKS] == [False, True, False]
    # the first look leaves out the costly last resort only; the second looks pay for the finer levels only
    # (not the enhanced copies, which the first look tried)
    own = Fallbacks()
    assert FIRST.passes == FIRST_PASSES and FIRST_PASSES[0](own) == Fallbacks(foreshortened=False)
    assert second_look_fallbacks(own) == Fallbacks(True, (0.5, 0.25), False, False, False, False)
    assert CORRECTED.passes == (second_look_fallbacks,) and FORESHORTENED.passes == (own_fallbacks,)
    # the calibrated look: the first level alone, then the second look's fallback levels alone
    assert [ask(own) for ask in CALIBRATED.passes] == [Fallbacks(True, (), False, False, False, False),
                                                      Fallbacks(False, (0.5, 0.25), False, False, False, False)]
    assert own == Fallbacks()  # a pass makes a new value, the detector's own stays as it is


def _counting_look(found_on_pass: int):
    calls = []

    def detect(tools, out, images, keys, board, fallbacks):
        calls.append((len(keys), fallbacks))
        hit = torch.full((images.shape[0],), len(calls) == found_on_pass)
        return DetectionResult(torch.ones(images.shape[0], 6, 2), hit, ["pass %d" % len(calls)] * images.shape[0])

    look = Look("test look", lambda out, detector: [], detect,
                (lambda own: own.but(levels=()), lambda own: own.but(primary=False)))
    return look, calls


def test_look_passes_run_on_what_the_passes_before_missed():
    look, calls = _counting_look(found_on_pass=2)
    tools = Tools(None, None, None, SimpleNamespace(fallbacks=Fallbacks()), 1)
    got = look.run(tools, None, torch.rand(3, 1, 8, 8), [(0, 0), (0, 1), (0, 2)], (3, 2))
    assert calls == [(3, Fallbacks(levels=())), (3, Fallbacks(primary=False))]
    assert got.found.tolist() == [True] * 3 and got.reasons == ["pass 2"] * 3


def test_look_passes_skipped_where_nothing_is_left_or_nothing_to_try():
    look, calls = _counting_look(found_on_pass=1)
    tools = Tools(None, None, None, SimpleNamespace(fallbacks=Fallbacks()), 1)
    look.run(tools, None, torch.rand(2, 1, 8, 8), [(0, 0), (0, 1)], (3, 2))
    assert len(calls) == 1  # every board found on the first pass
    look, calls = _counting_look(found_on_pass=0)
    look.run(Tools(None, None, None, SimpleNamespace(fallbacks=None), 1), None, torch.rand(2, 1, 8, 8),
             [(0, 0), (0, 1)], (3, 2))
    assert calls == [(2, None)]  # a detector without fallbacks: a second pass would be the first again
    look, calls = _counting_look(found_on_pass=0)
    nothing = Fallbacks(levels=(), opencv=False, foreshortened=False, copies=False)
    look.run(Tools(None, None, None, SimpleNamespace(fallbacks=nothing), 1), None, torch.rand(2, 1, 8, 8),
             [(0, 0), (0, 1)], (3, 2))
    assert len(calls) == 1  # the second pass (no primary level, no fallback level) would try nothing


def test_the_pipeline_takes_its_looks():
    from ccs_kornia.pipeline.calibration_pipeline import CalibrationPipeline

    kw = dict(distortion_correction=False)
    assert CalibrationPipeline("opencv", **kw).settings.looks == LOOKS
    assert CalibrationPipeline("opencv", calibrated_look=False, **kw).settings.looks == (CORRECTED, FORESHORTENED)
    assert CalibrationPipeline("opencv", looks=(FORESHORTENED,), **kw).settings.looks == (FORESHORTENED,)
