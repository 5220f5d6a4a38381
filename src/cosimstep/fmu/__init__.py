"""FMI support: building cosimstep's own test FMUs from C sources (:mod:`cosimstep.fmu.build`).

The sub-model adapter that runs FMUs lives in :mod:`cosimstep.adapters.fmu`.
"""
