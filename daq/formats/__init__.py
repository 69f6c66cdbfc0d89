"""Lab file formats: import time data from TDMS, UFF 58 and CSV into fnsi-lab recordings.

>>> from fnsi_lab.daq.formats import read_lab_file, plan_import, write_recording
>>> table = read_lab_file("run.tdms")                     # LabTable: data, channels, rate
>>> plan = plan_import(table, inputs=["F-X3"], samples_per_period=8192)
>>> write_recording(table, plan, "run.mcap")

``fnsi-lab import`` is the command-line form (``docs/formats.md``).
"""

from fnsi_lab.daq.formats.dof import (direction_code, direction_from_code, parse_node_direction,
                                      quantity_from_unit)
from fnsi_lab.daq.formats.errors import LabFileError
from fnsi_lab.daq.formats.importer import (ImportPlan, plan_import, read_lab_file,
                                           write_recording)
from fnsi_lab.daq.formats.table import LabChannel, LabTable

__all__ = ["ImportPlan", "LabChannel", "LabFileError", "LabTable", "direction_code",
           "direction_from_code", "parse_node_direction", "plan_import", "quantity_from_unit",
           "read_lab_file", "write_recording"]
