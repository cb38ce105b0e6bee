"""``python -m mcdenoise --version``: the package's version and methods."""
import sys

from . import METHODS, __version__


def main(argv):
    if argv[1:] in (["--version"], ["-V"]):
        print("mcdenoise %s" % __version__)
        return 0
    print("mcdenoise %s: call mcdenoise.denoise(...) or mcdenoise.Denoiser(...) from Python "
          "(methods: %s); the command line is the `mcdenoise` binary. Options: --version" % (__version__, ", ".join(METHODS)))
    return 0 if len(argv) == 1 else 2


if __name__ == "__main__":
    sys.exit(main(sys.argv))
