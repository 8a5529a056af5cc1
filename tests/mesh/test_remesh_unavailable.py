"""Without the optional mesher, remeshing says how to install it (runs whether or not TetGen is installed)."""

import sys

import numpy as np
import pytest

from idp.errors import IdpError, MesherUnavailableError
from idp.mesh.generate import tet_box
from idp.mesh.remesh import mesher_available, remesh_volume


def test_missing_tetgen_names_the_extra(monkeypatch):
    monkeypatch.setitem(sys.modules, "tetgen", None)  # makes `import tetgen` raise ImportError
    assert not mesher_available()
    mesh = tet_box(resolution=1)
    with pytest.raises(MesherUnavailableError, match=r'pip install "idp\[remesh\]"') as info:
        remesh_volume(mesh.vertices, np.asarray(mesh.elements))
    assert isinstance(info.value, IdpError)
