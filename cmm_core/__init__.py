"""CMM error lab core: data, kinematic error model, fitting, uncertainty, GP, diagnosis.

Lengths are mm in files and in the geometry; errors and residuals are µm; rotations µrad.
"""

__version__ = "0.1.0"
