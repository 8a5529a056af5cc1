"""The paper's data folder for the benchmarks (see :mod:`idp.paper_data`)."""

from idp.paper_data import find_data_dir, require_data_dir

__all__ = ["find_data_dir", "require_data_dir"]
