"""C sources of the FMUs (installed as ``lpvpc.export.c``): the generic FMI 2/3
co-simulation wrapper (``wrapper/``), the model adapter (``model/``) and the actuator
(``actuator/``). Package data only; ``lpvpc.export.fmu_build`` compiles them."""
