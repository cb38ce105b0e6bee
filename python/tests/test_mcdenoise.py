"""mcdenoise from Python against the command line, the error paths, and
the array layouts it takes (run by .ci/run in a fresh virtual environment).
"""
import os
import pathlib
import signal
import subprocess
import sys
import tempfile
import threading
import time

import numpy as np
import pytest

import mcdenoise

ROOT = pathlib.Path(__file__).resolve().parents[2]
SAMPLE = ROOT / "samples"
BIN = pathlib.Path(os.environ.get("MCDENOISE", ROOT / "target" / "release" / "mcdenoise"))


def frames():
    return [mcdenoise.read_exr(SAMPLE / ("frame_%04d.exr" % i)) for i in range(8)]


def buffers(f):
    return {k: f[k] for k in ("albedo", "normal", "depth", "position", "motion", "second") if k in f}


def read_rgb(path):
    import OpenEXR
    with OpenEXR.File(str(path), separate_channels=True) as f:
        ch = f.channels()
        return np.stack([np.asarray(ch[c].pixels, dtype=np.float32) for c in "RGB"], axis=-1)


@pytest.mark.parametrize("method,extra", [
    ("atrous", []), ("sure-atrous", []), ("wskp", ["--layers", "3"]), ("afn", []), ("ta", []), ("cross", []),
])
@pytest.mark.parametrize("precision", ["f32", "fixed"])
def test_outputs_equal_the_command_line_bit_for_bit(method, extra, precision):
    if method == "cross" and precision != "f32":
        pytest.skip("cross trains online in f32 only")
    if not BIN.exists():
        pytest.fail("the mcdenoise binary is not built (cargo build --release): %s" % BIN)
    with tempfile.TemporaryDirectory() as out:
        subprocess.run([str(BIN), "denoise", "--quiet", "--float", "--threads", "2", "--method", method,
                        "--precision", precision] + extra + [str(SAMPLE), "-o", out], check=True)
        opts = {"layers": 3} if method == "wskp" else {}
        d = mcdenoise.Denoiser(method, precision=precision, threads=2, **opts)
        for i, f in enumerate(frames()):
            got = d.denoise(f["color"], **buffers(f))
            want = read_rgb(pathlib.Path(out) / ("frame_%04d.exr" % i))
            assert got.dtype == np.float32 and got.shape == want.shape
            assert np.array_equal(got, want), "%s %s frame %d differs from the CLI" % (method, precision, i)


def test_one_frame_function_and_threads():
    f = frames()[0]
    a = mcdenoise.denoise(f["color"], **buffers(f), method="atrous", threads=1)
    b = mcdenoise.denoise(f["color"], **buffers(f), method="atrous", threads=2)
    assert np.array_equal(a, b), "the thread count does not change the output"


def test_strided_and_float16_inputs():
    f = frames()[0]
    c = f["color"]
    # A strided view (every channel of a wider array, reversed rows twice = same image).
    wide = np.zeros((c.shape[0], c.shape[1], 5), np.float32)
    wide[..., 1:4] = c
    strided = wide[..., 1:4]
    assert not strided.flags["C_CONTIGUOUS"]
    a = mcdenoise.denoise(c, albedo=f["albedo"], method="atrous")
    b = mcdenoise.denoise(strided, albedo=np.asfortranarray(f["albedo"]), method="atrous")
    assert np.array_equal(a, b)
    h = mcdenoise.denoise(c.astype(np.float16), albedo=f["albedo"].astype(np.float16), method="atrous")
    c16 = c.astype(np.float16).astype(np.float32)
    a16 = mcdenoise.denoise(c16, albedo=f["albedo"].astype(np.float16).astype(np.float32), method="atrous")
    assert np.array_equal(h, a16), "float16 arrays read as their float32 values"


def test_missing_buffers_skip_stages_or_say_which():
    f = frames()[0]
    out = mcdenoise.denoise(f["color"], method="atrous")
    assert out.shape == f["color"].shape
    d = mcdenoise.Denoiser("atrous")
    d.denoise(f["color"])
    assert "skipped" in d.plan and "albedo" in d.plan
    with pytest.raises(ValueError, match="albedo"):
        mcdenoise.denoise(f["color"], method="wskp")
    with pytest.raises(ValueError, match="second estimate"):
        mcdenoise.denoise(f["color"], albedo=f["albedo"], method="cross")


@pytest.mark.parametrize("call,kind,text", [
    (lambda c: mcdenoise.denoise(c, method="nope"), ValueError, "method: expected one of"),
    (lambda c: mcdenoise.denoise(c, precision="f64"), ValueError, "precision: expected one of"),
    (lambda c: mcdenoise.denoise(c, threads=0), ValueError, "threads"),
    (lambda c: mcdenoise.denoise(c, phi_color=-1.0), ValueError, "phi_color: expected a positive number"),
    (lambda c: mcdenoise.denoise(c, method="wskp", layers=4), ValueError, "layers: expected 3 or 6"),
    (lambda c: mcdenoise.denoise(c, bogus=1), TypeError, "unexpected keyword argument 'bogus'"),
    (lambda c: mcdenoise.denoise(c.astype(np.float64)), TypeError, "float32 or float16"),
    (lambda c: mcdenoise.denoise(c[..., :2]), ValueError, "3 channels"),
    (lambda c: mcdenoise.denoise(c, albedo=c[:10]), ValueError, "albedo: the array is"),
    (lambda c: mcdenoise.denoise(c[0]), ValueError, "3 channels in the last axis, got 1"),
    (lambda c: mcdenoise.denoise(c[None]), ValueError, "H x W x C"),
    (lambda c: mcdenoise.denoise("not an array"), TypeError, "float32 or float16"),
    (lambda c: mcdenoise.denoise(c[:0]), ValueError, "empty"),
    (lambda c: mcdenoise.denoise(c, method="wskp", weights="/nonexistent.safetensors",
                                 albedo=c, normal=c, depth=c[..., 0]), ValueError, "nonexistent"),
])
def test_every_bad_input_raises_with_the_message(call, kind, text):
    c = frames()[0]["color"]
    with pytest.raises(kind, match=text):
        call(c)


def test_a_size_change_mid_sequence_is_an_error():
    f = frames()
    d = mcdenoise.Denoiser("ta")
    d.denoise(f[0]["color"], **buffers(f[0]))
    with pytest.raises(ValueError, match="make a new denoiser"):
        d.denoise(f[1]["color"][:-1], **{k: v[:-1] for k, v in buffers(f[1]).items()})


def test_sequences_keep_state_and_reset_forgets_it():
    f = frames()
    d = mcdenoise.Denoiser("ta")
    for i in range(3):
        third = d.denoise(f[i]["color"], **buffers(f[i]))
    assert d.frames == 3
    d.reset()
    again = d.denoise(f[2]["color"], **buffers(f[2]))
    # (The second frame takes all of the current one: the first has no history.)
    assert not np.array_equal(third, again), "history was used"
    # (The sample carries the second estimate: the colour is the pair's mean.)
    assert np.array_equal(again, np.float32(0.5) * (f[2]["color"] + f[2]["second"])), \
        "after reset the frame starts a sequence"
    assert d.frames == 1


def test_cross_state_saves_and_loads():
    f = frames()
    with tempfile.TemporaryDirectory() as t:
        path = os.path.join(t, "state.safetensors")
        d = mcdenoise.Denoiser("cross", threads=2)
        for i in range(3):
            d.denoise(f[i]["color"], **buffers(f[i]))
        d.save_state(path)
        a = d.denoise(f[3]["color"], **buffers(f[3]))
        e = mcdenoise.Denoiser("cross", threads=2, load_state=path)
        # The same state, a new sequence: no history, so compare weights through a second save.
        e.denoise(f[3]["color"], **buffers(f[3]))
        assert os.path.getsize(path) > 1000 and a.shape == f[3]["color"].shape
        with pytest.raises(ValueError, match="keeps no state"):
            mcdenoise.Denoiser("atrous").load_state(path)


def test_the_gil_is_released_while_denoising():
    f = frames()[0]
    ticks = []
    stop = threading.Event()

    def tick():
        while not stop.is_set():
            ticks.append(time.perf_counter())
            time.sleep(0.001)

    t = threading.Thread(target=tick)
    t.start()
    start = time.perf_counter()
    d = mcdenoise.Denoiser("sure-atrous", threads=1)
    for _ in range(5):
        d.denoise(f["color"], **buffers(f))
    end = time.perf_counter()
    stop.set()
    t.join()
    during = [x for x in ticks if start < x < end]
    assert len(during) > 5, "another Python thread ran while the kernels did"


def test_ctrl_c_interrupts_between_frames():
    # Python's own Ctrl-C handler, as in a terminal: a shell that starts the
    # suite in the background without job control leaves SIGINT ignored,
    # which Python and this child inherit.
    script = (
        "import signal\n"
        "signal.signal(signal.SIGINT, signal.default_int_handler)\n"
        "import mcdenoise, numpy as np, sys\n"
        "c = np.random.default_rng(1).random((720, 1280, 3), dtype=np.float32)\n"
        "d = mcdenoise.Denoiser('sure-atrous', threads=1)\n"
        "print('ready', flush=True)\n"
        "try:\n"
        "    for _ in range(10000):\n"
        "        d.denoise(c)\n"
        "except KeyboardInterrupt:\n"
        "    print('interrupted', flush=True)\n"
        "    sys.exit(3)\n"
    )
    p = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, text=True)
    assert p.stdout.readline().strip() == "ready"
    time.sleep(1.0)
    p.send_signal(signal.SIGINT)
    out, _ = p.communicate(timeout=60)
    assert p.returncode == 3 and "interrupted" in out


def test_help_and_version():
    assert "method:" in mcdenoise.denoise.__doc__ and "albedo" in mcdenoise.denoise.__doc__
    assert "sequence" in mcdenoise.Denoiser.__doc__
    out = subprocess.run([sys.executable, "-m", "mcdenoise", "--version"],
                         capture_output=True, text=True, check=True).stdout
    assert out.strip() == "mcdenoise %s" % mcdenoise.__version__
    assert set(mcdenoise.METHODS) == {"none", "ta", "atrous", "sure-atrous", "wskp", "afn", "cross"}


def test_pair_matches_the_command_line():
    # The pair's mean (the default) and the first estimate alone, as the
    # CLI's --pair mean / first give them; 'none' shows the colour used.
    f = frames()
    for use in ("mean", "first"):
        for method in ("none", "wskp"):
            with tempfile.TemporaryDirectory() as out:
                subprocess.run([str(BIN), "denoise", "--quiet", "--float", "--threads", "2", "--method", method,
                                "--pair", use, str(SAMPLE), "-o", out], check=True)
                d = mcdenoise.Denoiser(method, threads=2, pair=use)
                for i, fr in enumerate(f):
                    got = d.denoise(fr["color"], **buffers(fr))
                    want = read_rgb(pathlib.Path(out) / ("frame_%04d.exr" % i))
                    assert np.array_equal(got, want), "%s pair=%s frame %d differs from the CLI" % (method, use, i)
                    if method == "none":
                        c = fr["color"] if use == "first" else np.float32(0.5) * (fr["color"] + fr["second"])
                        assert np.array_equal(got, c), "none pair=%s frame %d is not the colour asked for" % (use, i)
    with pytest.raises(ValueError, match="pair: expected"):
        mcdenoise.Denoiser("ta", pair="both")
    with pytest.raises(ValueError, match="--pair first"):
        mcdenoise.denoise(f[0]["color"], **buffers(f[0]), method="cross", pair="first")


def ta_option_matches_the_command_line(cli, kw, what):
    # TA with a CLI option and with its keyword: equal frame by frame; and
    # the option changes some frame of the sample against TA's default.
    with tempfile.TemporaryDirectory() as out:
        subprocess.run([str(BIN), "denoise", "--quiet", "--float", "--threads", "2", "--method", "ta"] + cli
                       + [str(SAMPLE), "-o", out], check=True)
        d = mcdenoise.Denoiser("ta", threads=2, **kw)
        default = mcdenoise.Denoiser("ta", threads=2)
        differs = False
        for i, f in enumerate(frames()):
            got = d.denoise(f["color"], **buffers(f))
            want = read_rgb(pathlib.Path(out) / ("frame_%04d.exr" % i))
            assert np.array_equal(got, want), "%s frame %d differs from the CLI" % (what, i)
            differs |= not np.array_equal(default.denoise(f["color"], **buffers(f)), got)
        assert differs, "%s changes no frame of the sample against TA's default" % what


def test_ta_reject_matches_the_command_line():
    # Off (the default is on): the keyword reaches the accumulation as
    # --ta-reject does.
    ta_option_matches_the_command_line(["--ta-reject", "0"], {"ta_reject": 0.0}, "ta_reject=0")


def test_ta_relight_matches_the_command_line():
    # Off (the default is on): the keyword reaches the accumulation as
    # --ta-relight off does.
    ta_option_matches_the_command_line(["--ta-relight", "off"], {"ta_relight": False}, "ta_relight=False")


def test_ta_reject_scales_matches_the_command_line():
    # TA at three scales as --ta-reject-scales 3 gives it (the default is
    # one); a count outside 1 to 3 is refused, naming the keyword.
    ta_option_matches_the_command_line(["--ta-reject-scales", "3"], {"ta_reject_scales": 3}, "ta_reject_scales=3")
    with pytest.raises(ValueError, match="ta_reject_scales: expected"):
        mcdenoise.Denoiser("ta", ta_reject_scales=4)
