"""lpvpc validation harness: co-simulate an identified model's FMU with the actuator FMU,
compare every prediction route with a held-out record and write the validation report.

Units: time s, angles rad, torque N m, rates Hz, VAF percent.

- :func:`validate` (:mod:`validation.harness`): the whole run, as ``lpvpc validate`` does it;
- :mod:`validation.cosim`: the co-simulation master (:func:`run_cosimulation`);
- :mod:`validation.fmu`: checked FMU loading and instances with the FMU's log captured;
- :mod:`validation.routes`: numpy, CasADi and FMU-replay predictions of a record;
- :mod:`validation.compare`: metrics; :mod:`validation.report`: figures, HTML, metrics.json.
"""

from .cosim import CosimSettings, run_cosimulation
from .harness import ValidationResult, validate

__all__ = ["validate", "ValidationResult", "CosimSettings", "run_cosimulation"]
