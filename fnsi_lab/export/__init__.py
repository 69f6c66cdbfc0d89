"""Exporting identification results to lab formats: UFF 55 modes, UFF 58 FRFs, CSV tables.

>>> from fnsi_lab.export import load_result, assign_dofs, uff_text, write_tables
>>> res = load_result("result.json")                     # fnsi-lab ident --json
>>> out_dofs, in_dofs = assign_dofs(res.outputs, res.inputs)   # nodes from names like NC2-Z
>>> text, notes = uff_text(res, out_dofs, in_dofs)

``fnsi-lab export`` is the command-line form (``docs/formats.md``).
"""

from fnsi_lab.export.dofs import (Dof, assign_dofs, channel_table_mapping, parse_mapping,
                                  read_mapping_file)
from fnsi_lab.export.result import ResultArrays, ResultFileError, load_result, result_from_dict
from fnsi_lab.export.tables import write_tables
from fnsi_lab.export.uff import (eigenvalue, mode_from_eigenvalue, number_field, uff55_mode,
                                 uff58_frf, uff_text)

__all__ = ["Dof", "ResultArrays", "ResultFileError", "assign_dofs", "channel_table_mapping",
           "eigenvalue",
           "load_result", "mode_from_eigenvalue", "number_field", "parse_mapping",
           "read_mapping_file", "result_from_dict", "uff55_mode", "uff58_frf", "uff_text",
           "write_tables"]
