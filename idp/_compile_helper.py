"""``python -m idp._compile_helper PACKAGE CLAIMS I...``: the second process of :func:`idp.kernel_cache.prepare`."""

import sys

from idp.kernel_cache import helper_main

if __name__ == "__main__":
    sys.exit(helper_main(sys.argv[1:]))
