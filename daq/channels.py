"""Channel metadata: what one column of a sample block holds."""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any, Literal, get_args

Quantity = Literal["displacement", "velocity", "acceleration", "force"]
QUANTITIES: tuple[str, ...] = get_args(Quantity)

#: SI unit of each quantity, used when a channel does not state its own.
DEFAULT_UNITS: dict[str, str] = {
    "displacement": "m",
    "velocity": "m/s",
    "acceleration": "m/s^2",
    "force": "N",
}


@dataclass(frozen=True)
class ChannelInfo:
    """One measured channel.

    Attributes
    ----------
    name : str
        Unique channel name, e.g. ``NC2W-Z``.
    quantity : {'displacement', 'velocity', 'acceleration', 'force'}
        Physical quantity. Force channels are the inputs of identification, the others
        are responses.
    unit : str
        Unit of the recorded values (recorded values are always physical, after the
        sensitivity has been applied).
    node : str
        Measurement node (``NC2W``); empty when unknown.
    direction : str
        Direction at the node (``X``, ``Y``, ``Z``); empty when unknown.
    sensitivity : float
        Transducer sensitivity (raw units per physical unit, e.g. V/N), kept for
        traceability; 1.0 when values arrive already in physical units.
    """

    name: str
    quantity: Quantity = "displacement"
    unit: str = ""
    node: str = ""
    direction: str = ""
    sensitivity: float = 1.0

    def __post_init__(self) -> None:
        if not self.unit:
            object.__setattr__(self, "unit", DEFAULT_UNITS.get(self.quantity, ""))

    @property
    def is_force(self) -> bool:
        """True for excitation (input) channels."""
        return self.quantity == "force"

    def to_dict(self) -> dict[str, Any]:
        """Plain-dict form (the MCAP channel table stores a list of these)."""
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> "ChannelInfo":
        """Inverse of :meth:`to_dict`; unknown keys are ignored (forward compatibility)."""
        known = {k: data[k] for k in ("name", "quantity", "unit", "node", "direction",
                                       "sensitivity") if k in data}
        return cls(**known)
