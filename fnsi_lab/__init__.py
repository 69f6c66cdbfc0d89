"""fnsi-lab: command-line glue shared by the `daq`, `ident`, `replay` and `viewer` packages.

The science lives in those four packages; this package only holds the version, the root of
the exception tree and the ``fnsi-lab`` command.
"""

__version__ = "0.1.0"
