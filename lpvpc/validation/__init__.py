"""lpvpc validation harness: co-simulate an identified model's FMU with the actuator FMU,
compare every prediction route with a held-out record and write the validation report.

Units: time s, angles rad, torque N m, rates Hz, VAF percent.

- :func:`~lpvpc.validation.harness.validate` (:mod:`lpvpc.validation.harness`): the whole run, as ``lpvpc validate`` does it;
- :mod:`lpvpc.validation.cosim`: the co-simulation master (:func:`~lpvpc.validation.cosim.run_cosimulation`);
- :mod:`lpvpc.validation.fmu`: checked FMU loading and instances with the FMU's log captured;
- :mod:`lpvpc.validation.routes`: numpy, CasADi and FMU-replay predictions of a record;
- :mod:`lpvpc.validation.compare`: metrics; :mod:`lpvpc.validation.report`: figures, HTML, metrics.json.
"""

from .cosim import CosimSettings, run_cosimulation
from .harness import ValidationResult, validate

__all__ = ["validate", "ValidationResult", "CosimSettings", "run_cosimulation"]
