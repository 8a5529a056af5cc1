"""idp: guaranteed globally injective deformation processing.

Layers (each a sub-package): ``mesh`` -> ``energies`` -> ``contact`` -> ``solver``
-> ``stepper`` -> ``scene`` -> ``output`` -> ``cli``. The Python API is :func:`simulate`
with :class:`Scene` (the same models a scene file is validated against).
"""

__version__ = "0.1.0"


def __getattr__(name):  # lazy: keep `import idp` cheap
    if name == "simulate":
        from idp.api import simulate

        return simulate
    if name == "load_scene":
        from idp.scene.load import load_scene

        return load_scene
    if name == "Scene":
        from idp.scene.schema import Scene

        return Scene
    raise AttributeError(name)
