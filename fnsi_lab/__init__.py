"""fnsi-lab: nonlinear structural identification in the test lab.

Public API (docs/api.md)::

    import fnsi_lab
    fnsi_lab.acquire(out="run.mcap")                         # record an experiment
    result = fnsi_lab.identify("run.mcap", config="smallsat39")   # FNSI, robust pipeline
    result.order, result.modes, result.coefficients, result.to_json()
    fnsi_lab.open_recording("run.mcap")                      # read a recording
    fnsi_lab.validate_model("result.json", "other.mcap")     # the model on another record

Sub-packages: :mod:`fnsi_lab.daq` (channels, sources, MCAP recording), :mod:`fnsi_lab.ident`
(FNSI on arrays), :mod:`fnsi_lab.replay` (recordings as streams, the live service),
:mod:`fnsi_lab.viewer` (Rerun). The API is imported lazily so that ``fnsi-lab --help`` and
``import fnsi_lab`` stay fast.
"""

from typing import Any

__version__ = "0.1.0"

__all__ = ["identify", "analyse", "locate", "open_recording", "acquire", "load_config", "Identification",
           "Mode", "Coefficient", "validate_model", "__version__"]


def __getattr__(name: str) -> Any:
    if name in ("identify", "analyse", "locate", "open_recording", "acquire", "load_config",
                "Identification"):
        from fnsi_lab import api

        return getattr(api, name)
    if name in ("Mode", "Coefficient"):   # the answer's records (docs/api.md, "The result")
        from fnsi_lab.ident.core import result

        return getattr(result, name)
    if name == "validate_model":   # fnsi_lab.validate is the YAML helper module
        from fnsi_lab.model_validation import validate_model

        return validate_model
    raise AttributeError(f"module 'fnsi_lab' has no attribute {name!r}")
