"""mcdenoise: real-time Monte Carlo denoisers on numpy arrays.

The same library as the ``mcdenoise`` command line (edge-avoiding à-trous,
its SURE variant, weight-sharing kernel prediction, the adaptive fusion
network, online cross-regression), called on H x W x C float32 or float16
arrays in memory::

    import mcdenoise
    out = mcdenoise.denoise(color, albedo=albedo, normal=normal, method="atrous")

    d = mcdenoise.Denoiser("wskp", layers=3)      # a sequence: keeps the history
    for frame in frames:
        out = d.denoise(frame["color"], albedo=frame["albedo"], normal=frame["normal"],
                        depth=frame["depth"], motion=frame["motion"])

``help(mcdenoise.denoise)`` and ``help(mcdenoise.Denoiser)`` list the
arrays and options; ``mcdenoise.read_exr(path)`` reads a frame file as the
command line does.
"""
from ._mcdenoise import METHODS, Denoiser, __version__, denoise, read_exr

__all__ = ["denoise", "Denoiser", "read_exr", "METHODS", "__version__"]
