"""A frame rendered by Mitsuba 3 in Python, denoised in memory
(python/examples/mitsuba_denoise.py). Skipped, with the reason, where
Mitsuba or its LLVM backend is missing; .ci/run installs both.
"""
import importlib.util
import os
import pathlib
import sys

import pytest

EXAMPLES = pathlib.Path(__file__).resolve().parents[1] / "examples"


def llvm_variant():
    if importlib.util.find_spec("mitsuba") is None:
        return "the mitsuba package is not installed (tools/setup-render.sh)"
    import mitsuba as mi
    try:
        mi.set_variant("llvm_ad_rgb")
    except Exception as e:  # no libLLVM
        return "Mitsuba's llvm_ad_rgb variant is unavailable (%s); tools/setup-render.sh installs libLLVM" % e
    return None


def test_render_and_denoise_in_memory():
    why = llvm_variant()
    if why:
        if os.environ.get("MCDENOISE_REQUIRE_MITSUBA"):
            pytest.fail(why)
        pytest.skip(why)
    sys.path.insert(0, str(EXAMPLES))
    import mitsuba_denoise
    before, after = mitsuba_denoise.render(4, "atrous", "llvm_ad_rgb")
    assert after > before + 8, "atrous gains over the 4-spp Cornell box: %.2f -> %.2f dB" % (before, after)
