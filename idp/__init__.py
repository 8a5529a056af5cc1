"""idp: guaranteed globally injective deformation processing.

Layers (each a sub-package): ``mesh`` -> ``energies`` -> ``contact`` -> ``solver``
-> ``stepper`` -> ``scene`` -> ``output`` -> ``cli``.
"""

__version__ = "0.1.0"
