"""Rod verdicts by class: what the data fix, which members fit with their sign, and what to do.

On one rod scan an offset, a gain, a beam tilt and a beam offset of one layer imitate each other (with l0
known and certified radii they are look-alikes in every scan; issue 17, point 2). "Ambiguous" is then right
but incomplete. The verdict also says, per layer:

- what the data fix: the layer's reading shift, ``layer 2 reads 12 +- 3 um long`` (its ``sensor_offset``
  member's fitted b);
- the class: ``offset-like``, absorbed by a calibration of the layer's l0;
- only members whose sign fits: a beam offset only shortens a reading (-d^2 / (2 r)), a beam tilt only
  lengthens it (1 / cos(gamma)); a gain either way;
- ``sensor_nonlinearity``: its bow has a second harmonic that some scans resolve; where it does, the bow
  is named on its own (it is then not tied with the class); where it fits as well as the class, it is a
  look-alike the class lists (``nonlinearity_also_fits``) and is not named apart;
- the advice: recalibrate l0 of the layer on a certified ring gauge.
"""

from __future__ import annotations

from dataclasses import dataclass, field

__all__ = ["OFFSET_LIKE", "LayerClass", "rod_classes"]

#: the members of the offset-like class of one rod layer, and the sign of the shift each can give
#: (+1 lengthens, -1 shortens, 0 either)
OFFSET_LIKE = {"sensor_offset": 0, "sensor_gain": 0, "beam_tilt": +1, "beam_offset": -1}
#: a shift counts as signed when it lies this many standard uncertainties from zero
SIGN_SIGMAS = 2.0


@dataclass
class LayerClass:
    """The offset-like class of one rod layer in a verdict."""

    channel: int
    shift_um: float | None
    u_shift_um: float | None
    members: list[str] = field(default_factory=list)
    dropped: list[str] = field(default_factory=list)
    nonlinearity: bool = False

    @property
    def sentence(self) -> str:
        """Return the class in words, with what the data fix and the advice."""
        if self.shift_um is not None:
            way = "long" if self.shift_um > 0 else "short"
            fixed = f"layer {self.channel} reads {abs(self.shift_um):.3g} +- {self.u_shift_um:.2g} um {way}"
        else:
            fixed = f"layer {self.channel} reads off by a constant"
        out = (
            f"{fixed}: offset-like ({', '.join(self.members)}), absorbed by a calibration of l0; "
            f"recalibrate l0 of layer {self.channel} on a certified ring gauge"
        )
        if self.nonlinearity:
            out += f"; a bow of sensor {self.channel} (sensor_nonlinearity) fits as well and is not resolved"
        return out

    def to_dict(self) -> dict:
        """Return the JSON-ready form (findings.json ``classes``)."""
        return {
            "class": "offset-like",
            "channel": self.channel,
            "reads_long_um": self.shift_um,
            "u_reads_long_um": self.u_shift_um,
            "members": self.members,
            "dropped_for_sign": self.dropped,
            "nonlinearity_also_fits": self.nonlinearity,
            "absorbed_by": "a calibration of l0_mm of the layer",
            "advice": f"recalibrate l0 of layer {self.channel} on a certified ring gauge",
            "statement": self.sentence,
        }


def _shift(entries: list[dict]) -> tuple[float | None, float | None]:
    """Return the layer's reading shift and its uncertainty [um] from its sensor_offset member, if named."""
    for n in entries:
        if n["effect"] == "sensor_offset":
            b, u = n["parameters"].get("b_mm"), n["uncertainties"].get("u_b_mm")
            if b is not None and u is not None:
                return 1e3 * float(b), 1e3 * float(u)
    return None, None


def rod_classes(named: list[dict]) -> tuple[list[dict], list[LayerClass]]:
    """Group a rod verdict's named entries into per-layer offset-like classes; drop wrong-sign members.

    Returns the named entries left (a member whose sign does not fit the layer's fixed shift removed, and a
    bow tied with its layer's class) and the classes of layers with at least two offset-like members.
    """
    by_layer: dict[int, list[dict]] = {}
    for n in named:
        if n["effect"] in OFFSET_LIKE and n.get("channel") is not None:
            by_layer.setdefault(int(n["channel"]), []).append(n)
    classes, drop = [], set()
    for ch, entries in sorted(by_layer.items()):
        shift, u = _shift(entries)
        sign = 0
        if shift is not None and u is not None and abs(shift) > SIGN_SIGMAS * u:
            sign = 1 if shift > 0 else -1
        members, dropped = [], []
        for n in entries:
            s = OFFSET_LIKE[n["effect"]]
            if sign and s and s != sign:
                dropped.append(n["effect"])
                drop.add(id(n))
            else:
                members.append(n["effect"])
        if len(members) < 2:
            continue
        nonlin = any(n["effect"] == "sensor_nonlinearity" and n.get("channel") == ch for n in named)
        classes.append(LayerClass(ch, shift, u, members, dropped, nonlin))
    for k in classes:  # a bow tied with the class is one of its look-alikes: listed in it, not named apart
        if k.nonlinearity:
            drop |= {
                id(n) for n in named if n["effect"] == "sensor_nonlinearity" and n.get("channel") == k.channel
            }
    return [n for n in named if id(n) not in drop], classes
