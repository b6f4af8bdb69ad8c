"""The virtual drive's own rules, asked by the bench and the plans for `hil run --check`.

`hil.bench.virtual_rules()` loads this module by name when a virtual bench's model
`options:` and `mechanics:`, an `inject:` step or a DI mapping needs judging, so `hil.bench`
and `hil.plan` never import the model (docs/architecture.md).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Any

from hil.model.dio import INERT_DI_FUNCTIONS, INERT_DO_FUNCTIONS, inert_mapping
from hil.model.errors import ModelError
from hil.model.mechanics import Mechanics
from hil.model.options import ModelOptions
from hil.virtual.options import FACE_ROOMS, model_options

__all__ = ["FACE_ROOMS", "INERT_DI_FUNCTIONS", "INERT_DO_FUNCTIONS", "Mechanics",
           "ModelOptions", "inert_mapping", "model_options", "param_writes_problem"]

_GEAR = ("P1.044", "P1.045")


def param_writes_problem(spec: Any, options: Mapping[str, Any],
                         writes: Iterable[tuple[str, int]]) -> tuple[str, str] | None:
    """(parameter, why) for the first of `writes` (a plan's `params:`, in its order) that the
    virtual drive of bench drive `spec` refuses at the start of a run: powered up with its
    wiring's and the bench's parameters and the model `options`, servo off. None when it
    takes them all. The drive judges each write as it would over the bus, so a rule that
    depends on other parameters (the e-gear's 1/4 < Nx/M < 262144 in a PT mode, L8547) is
    judged in the plan's order."""
    from hil.model.drive import Drive  # the whole model: only when a plan has params
    from hil.virtual.world import initial_params

    params = initial_params(spec)
    writes = list(writes)

    def fresh() -> Drive:
        return Drive(options=model_options(options), params=dict(params))

    def first_refused(order: list[tuple[str, int]]) -> tuple[str, str] | None:
        d = fresh()
        for name, value in order:
            try:
                d.params.write(name, value)
            except ModelError as e:  # the field names the parameter: not said twice
                return name, str(e).removeprefix(f"{name}: ")
        return None

    bad = first_refused(writes)
    if bad is None or bad[0] not in _GEAR or not all(g in dict(writes) for g in _GEAR):
        return bad
    # both halves of the gear are written: say whether the other order reaches the pair
    target = dict(writes)
    swapped = [w for w in writes if w[0] not in _GEAR] + [
        (g, target[g]) for g in (_GEAR if bad[0] == "P1.045" else _GEAR[::-1])]
    if first_refused(swapped) is None:
        return bad  # the drive's own words say to write the other one first
    start = fresh().params
    n0, m0 = start.get("P1.044"), start.get("P1.045")
    why = bad[1].split("; write the ")[0]  # that advice would not help here
    return bad[0], (f"{why}; neither order reaches {target['P1.044']}/{target['P1.045']} "
                    f"from the drive's {n0}/{m0} in one write each: go through a pair inside "
                    "the range (a `write:` step), or set the option pt_gear_check: off")
