"""Drive parameters P0.xxx-P7.xxx: validation, retention, Modbus words (the runtime store).

The table (`ParamSpec`, `ParamTable`, `parse_name`, `canonical`) is `hil.profile.params`,
read from `fixtures/drive/a3_parameters.csv` (columns: fixtures/drive/README.md).
Values are raw integers in communication units, as Modbus and SDO carry them.

Attributes (§8.1, L6719-6723): ★ read-only, ▲ not writable while Servo On,
● takes effect after a power cycle, ■ not retained at power-off.

Addressing: Modbus address of Pg.n = (g << 8) + 2*n, low word first (L7156, L8492);
CANopen index = 0x2000 + (g << 8) + n (Pa-bc <=> 2aBCh, L18154-18156).
Choices on ambiguous points: docs/manual-choices.md#parameters.
"""

from __future__ import annotations

import contextlib
import json
import os
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path
from typing import Any

from hil.model.errors import OutOfRange, ProtectedParameter, ReadOnly, ServoOnLocked
from hil.profile.params import WRITE_ZERO_ONLY, ParamSpec, ParamTable, digit_problem

WriteHook = Callable[[str, int, int], None]
ReadHook = Callable[[], int]
ChangeListener = Callable[[str, int], None]
Validator = Callable[[str, int], None]

# the calibration parameters a reset (P2.008 = 10) leaves: "本參數無法重置" (L10947-11039)
NOT_RESETTABLE = frozenset(f"P4.{n:03d}" for n in range(11, 22))

# Parameters writable only after a P2.008 key (L9212-L9227): P2.071 (absolute position reset)
# after 271 (L10081, L16454); P4.010 (calibration) after 20 (L10938, L16043); P4.011-P4.021
# (hardware offsets) after 22 (L10947, L16045). Each entry: (key parameter, value, lines).
PROTECTED_KEYS: dict[str, tuple[str, int, str]] = {
    "P2.071": ("P2.008", 271, "L10081, L16454"),
    "P4.010": ("P2.008", 20, "L10938, L16043"),
    **{f"P4.{n:03d}": ("P2.008", 22, "L10947, L16045") for n in range(11, 22)},
}


class ParameterStore:
    """Parameter values as the drive keeps them.

    `read()` is what communication returns (the last value written); `get()` is the value in
    effect, which differs for ● parameters written but not yet power cycled (L6722).
    """

    def __init__(
        self,
        table: ParamTable | None = None,
        *,
        retained_path: Path | None = None,
        autosave: bool = True,
    ) -> None:
        self.table = table if table is not None else ParamTable.load()
        self.retained_path = Path(retained_path) if retained_path is not None else None
        self.autosave = autosave
        self.servo_on: Callable[[], bool] = lambda: False
        self._stored: dict[str, int] = {}
        self._effective: dict[str, int] = {}
        self._write_hooks: dict[str, list[WriteHook]] = {}
        self._read_hooks: dict[str, ReadHook] = {}
        self._peek_hooks: dict[str, ReadHook] = {}  # current value without read side effects
        self._validators: dict[str, list[Validator]] = {}
        self._listeners: list[ChangeListener] = []
        # RAM-only writes (a PR WRITE without ROM, L4533): the EEPROM value each reverts to
        # at the next power cycle, and the one `save` keeps
        self._eeprom: dict[str, int] = {}
        self._ram_only = 0  # > 0 inside `ram_only_writes`: every write goes to RAM alone
        # P2.030 function 5 (set by the drive): "各參數之設定值於斷電後不保持" (L9495), every
        # write from then on goes to RAM alone, whichever path it takes
        self.no_eeprom = False
        # bumped at every change of a value in effect or of the read hooks (`cached`)
        self.version = 0
        self._set_all_defaults()
        if self.retained_path is not None and self.retained_path.exists():
            self._load_retained()

    # -- access ------------------------------------------------------------------------------

    def spec(self, name: str) -> ParamSpec:
        return self.table.spec(name)

    def read(self, name: str) -> int:
        """Value as read over communication (live values through on_read hooks)."""
        spec = self.table.spec(name)
        hook = self._read_hooks.get(spec.param)
        return int(hook()) if hook is not None else self._stored[spec.param]

    def get(self, name: str) -> int:
        """Value in effect (● parameters: the value from the last power cycle)."""
        value = self._effective.get(name)  # fast path: a canonical name without a read hook
        if value is not None and name not in self._read_hooks:
            return value
        spec = self.table.spec(name)
        hook = self._read_hooks.get(spec.param)
        return int(hook()) if hook is not None else self._effective[spec.param]

    def peek(self, name: str) -> int:
        """The value a read would give, without a read's side effects (the data array's
        pointer P5.011 does not advance): the peek hook where there is one, else the read
        hook (a live value), else the stored value."""
        spec = self.table.spec(name)
        hook = self._peek_hooks.get(spec.param)
        if hook is not None:
            return int(hook())
        if spec.param in self._read_hooks:  # a live value without a separate peek
            return int(self._read_hooks[spec.param]())
        return self._stored[spec.param]

    def stored(self, name: str) -> int:
        """The stored (last written) value, bypassing on_read hooks."""
        return self._stored[self.table.spec(name).param]

    def pending(self) -> dict[str, int]:
        """● parameters written but not yet in effect: name -> written value."""
        return {k: v for k, v in self._stored.items() if self._effective[k] != v}

    def check_write(self, name: str, value: int) -> ParamSpec:
        """Validate a write like the drive does; raise the precise ParamError, else the spec."""
        spec = self.table.spec(name)
        if spec.read_only:
            raise ReadOnly(spec.param, "read-only (★, L6719)")
        if not isinstance(value, int) or isinstance(value, bool):
            raise OutOfRange(spec.param, f"value {value!r} is not an integer")
        if spec.param in WRITE_ZERO_ONLY and value != 0:
            raise OutOfRange(
                spec.param, f"only 0 (alarm reset) may be written, got {value} (L7079-7083)"
            )
        if not spec.min <= value <= spec.max:
            raise OutOfRange(
                spec.param,
                f"{spec.format(value)} outside {spec.format(spec.min)}..{spec.format(spec.max)}"
                f" (min {spec.min}, max {spec.max})",
            )
        if (why := digit_problem(spec.param, value)) is not None:
            raise OutOfRange(spec.param, why)
        if spec.servo_off_only and self.servo_on():
            raise ServoOnLocked(spec.param, "not writable while Servo On (▲, L6720)")
        key = PROTECTED_KEYS.get(spec.param)
        if key is not None and self._stored[key[0]] != key[1]:
            raise ProtectedParameter(spec.param, f"write {key[0]} = {key[1]} first ({key[2]})")
        for validate in self._validators.get(spec.param, ()):
            validate(spec.param, value)
        return spec

    def write(self, name: str, value: int, *, ram_only: bool = False) -> None:
        """Write as communication / panel does: validated, then write hooks fire.
        `ram_only`: into RAM alone (a PR WRITE without ROM, "ROM 為同時寫入 RAM 與 EEPROM，提供參數
        斷電保持的功能" L4533): the value in EEPROM comes back at the next power cycle."""
        spec = self.check_write(name, value)
        self._commit(spec, value, ram_only=ram_only)

    def persist(self) -> None:
        """Save the retained values now (with `autosave`), as a changing `write` does."""
        if self.autosave and self.retained_path is not None:
            self.save()

    def set_as_written(self, name: str, value: int) -> None:
        """A drive-side update that stands for a write of `name` (a CiA 402 object that is
        a parameter: 6080h = P1.055): kept as a write now would be (RAM-only with P2.030
        function 5 or inside `ram_only_writes`), saved as a write is."""
        self.set_internal(name, value, ram_only=self.ram_only_now())
        self.persist()

    def ram_only_now(self) -> bool:
        """Whether a write now goes to RAM alone: P2.030 function 5 on (`no_eeprom`), or
        inside `ram_only_writes`."""
        return self.no_eeprom or self._ram_only > 0

    @contextlib.contextmanager
    def ram_only_writes(self, on: bool = True) -> Iterator[None]:
        """Inside: every `write` goes to RAM alone, as a RAM-only one (a CANopen RPDO with
        P3.011.X = 0, L10764-10768)."""
        self._ram_only += bool(on)
        try:
            yield
        finally:
            self._ram_only -= bool(on)

    def set_internal(self, name: str, value: int, ram_only: bool = False) -> None:
        """Drive-side update (monitor values, P0.001, P4.000 history ...): no attribute checks.

        Takes effect at once (also for ● parameters); write hooks do not fire. `ram_only`: a
        running count (P5.038, P5.058 counting down): the stored value comes back at the next
        power cycle, as a RAM-only write's does."""
        spec = self.table.spec(name)
        value = int(value)
        self._note_eeprom(spec.param, ram_only)
        old = self._stored[spec.param]
        self._stored[spec.param] = value
        self._effective[spec.param] = value
        self.version += 1
        if old != value:
            self._notify(spec.param, value)

    # -- hooks -------------------------------------------------------------------------------

    def on_write(self, name: str, fn: WriteHook) -> Callable[[], None]:
        """Call fn(name, old, new) after every successful write() of `name`; returns remover."""
        key = self.table.spec(name).param
        self._write_hooks.setdefault(key, []).append(fn)
        return lambda: self._write_hooks[key].remove(fn)

    def on_read(self, name: str, fn: ReadHook) -> None:
        """Compute `name` on every read()/get()/Modbus read (live monitor values)."""
        self._read_hooks[self.table.spec(name).param] = fn
        self.version += 1

    def cached(self, *names: str) -> Callable[[], tuple[int, ...]]:
        """A getter of the values in effect of `names` (as `get`), looked up again only after
        a change: the model's per-step reads cost one compare, not a lookup per name. A
        parameter with a read hook (a live monitor value) is looked up at every call."""
        keys = tuple(self.table.spec(n).param for n in names)
        state: list[Any] = [-1, ()]

        def values() -> tuple[int, ...]:
            if state[0] != self.version:
                state[1] = tuple(self.get(k) for k in keys)
                live = any(k in self._read_hooks for k in keys)
                state[0] = -1 if live else self.version
            return state[1]

        return values

    def on_peek(self, name: str, fn: ReadHook) -> None:
        """The current value of `name` where a read has side effects (the data-array windows
        P5.012/P5.013 advance P5.011): the other half of a one-word Modbus write."""
        self._peek_hooks[self.table.spec(name).param] = fn

    def on_validate(self, name: str, fn: Validator) -> None:
        """fn(name, value) runs before every write() of `name` and may raise a ModelError."""
        self._validators.setdefault(self.table.spec(name).param, []).append(fn)

    def subscribe(self, fn: ChangeListener) -> Callable[[], None]:
        """fn(name, value) on every stored-value change (for ParamChanged events)."""
        self._listeners.append(fn)
        return lambda: self._listeners.remove(fn)

    # -- Modbus words ------------------------------------------------------------------------

    def by_modbus_address(self, address: int) -> ParamSpec:
        return self.table.by_modbus_address(address)

    def by_od_index(self, index: int) -> ParamSpec:
        return self.table.by_od_index(index)

    def modbus_read(self, address: int, count: int) -> list[int]:
        """`count` 16-bit words from `address` (every parameter spans two words, low first)."""
        if count < 0:
            raise ValueError(f"negative word count {count}")
        words: list[int] = []
        values: dict[str, int] = {}  # one read per parameter: read hooks may count (P5.012)
        # every address resolved before any read hook runs: a read refused for an undefined
        # address (exception 02h) must not advance the data-array address P5.011 (L5108-5114)
        specs = [self.table.by_modbus_address(a) for a in range(address, address + count)]
        for addr, spec in zip(range(address, address + count), specs, strict=True):
            if spec.param not in values:
                values[spec.param] = self.read(spec.param)
            low, high = spec.to_words(values[spec.param])
            words.append(high if addr & 1 else low)
        return words

    def modbus_write(self, address: int, words: Iterable[int]) -> None:
        """Write 16-bit words from `address`; all parameters touched are validated first.

        A 32-bit parameter written by one half only combines it with its current other half
        (the drive stores the half). For a 16-bit parameter the low word is the value and a
        high-word write is accepted and ignored. docs/manual-choices.md#parameters.
        """
        halves: dict[str, dict[int, int]] = {}
        specs: dict[str, ParamSpec] = {}
        order: list[str] = []
        for offset, word in enumerate(words):
            addr = address + offset
            if not 0 <= word <= 0xFFFF:
                raise OutOfRange(f"address 0x{addr:04X}", f"word {word} is not 16-bit")
            spec = self.table.by_modbus_address(addr)
            if spec.param not in halves:
                halves[spec.param] = {}
                specs[spec.param] = spec
                order.append(spec.param)
            halves[spec.param][addr & 1] = word
        plan: list[tuple[ParamSpec, int]] = []
        for key in order:
            spec, got = specs[key], halves[key]
            if spec.size == 16 and 0 not in got:
                continue  # only the (ignored) high word of a 16-bit parameter
            if 0 in got and 1 in got:  # both halves given: the current value is not needed
                cur_low = cur_high = 0
            else:
                cur_low, cur_high = spec.to_words(self.peek(key))
            value = spec.from_words(got.get(0, cur_low), got.get(1, cur_high))
            plan.append((self.check_write(key, value), value))
        for spec, value in plan:
            self._commit(spec, value)

    # -- power cycle and retention ----------------------------------------------------------

    def power_cycle(self) -> list[str]:
        """● values take effect, ■ values revert to default; returns names whose value changed."""
        changed: list[str] = []
        for key, value in self._eeprom.items():  # RAM-only writes are lost (L4533)
            if self._stored[key] != value:
                self._stored[key] = value
                self._notify(key, value)
        self._eeprom.clear()
        for spec in self.table:
            key = spec.param
            if spec.not_retained:
                if self._stored[key] != spec.default or self._effective[key] != spec.default:
                    changed.append(key)
                    self._stored[key] = spec.default
                    self._effective[key] = spec.default
                    self._notify(key, spec.default)
            elif self._effective[key] != self._stored[key]:
                self._effective[key] = self._stored[key]
                changed.append(key)
        self.version += 1
        if self.retained_path is not None:
            self.save()
        return changed

    def backup_to_eeprom(self) -> None:
        """Every value now in RAM becomes the EEPROM's (P2.030 = 8, "備分所有參數(目前值)到
        EEPROM 中，下次開電數值仍在", L9501): RAM-only writes are kept from then on."""
        self._eeprom.clear()
        self.persist()

    def factory_reset(self) -> None:
        """P2.008 = 10 "參數重置(重置後請重新上電)" (L9222): every parameter a user writes back
        to its default in EEPROM, in effect at the power cycle the manual asks for (as a ●
        one: until then the drive runs on the values it has, a read gives the reset one);
        not P4.011-P4.021 ("無法重置", L10947-11039) nor the read-only ★ ones (monitors, the
        alarm history). Write hooks do not fire; listeners hear it."""
        self._eeprom.clear()
        for spec in self.table:
            key = spec.param
            if spec.read_only or key in NOT_RESETTABLE or self._stored[key] == spec.default:
                continue
            self._stored[key] = spec.default
            self._notify(key, spec.default)
        self.version += 1
        self.persist()

    def reset_defaults(self) -> None:
        """Every parameter back to its default, in effect at once (P2.008 = 10 + power cycle)."""
        self._eeprom.clear()
        for spec in self.table:
            if self._stored[spec.param] != spec.default:
                self._stored[spec.param] = spec.default
                self._notify(spec.param, spec.default)
            self._effective[spec.param] = spec.default
        self.version += 1
        self.persist()

    def save(self, path: Path | None = None) -> None:
        """Write retained (non-■) values that differ from default to JSON."""
        path = Path(path) if path is not None else self.retained_path
        if path is None:
            raise ValueError("no retained_path to save parameters to")
        eeprom = self._eeprom
        data = {
            spec.param: eeprom.get(spec.param, self._stored[spec.param])
            for spec in self.table
            if spec.retained and eeprom.get(spec.param, self._stored[spec.param]) != spec.default
        }
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(path.suffix + ".tmp")
        tmp.write_text(json.dumps({"parameters": data}, indent=1, sort_keys=True))
        os.replace(tmp, path)

    def _load_retained(self) -> None:
        assert self.retained_path is not None
        try:
            data = json.loads(self.retained_path.read_text())["parameters"]
        except (OSError, ValueError, KeyError, TypeError) as exc:
            raise ValueError(f"{self.retained_path}: not a parameter file ({exc})") from exc
        for name, value in data.items():
            spec = self.table.spec(name)
            if spec.retained and spec.min <= int(value) <= spec.max:
                self._stored[spec.param] = int(value)
                self._effective[spec.param] = int(value)
        self.version += 1

    # -- internals ---------------------------------------------------------------------------

    def _set_all_defaults(self) -> None:
        for spec in self.table:
            self._stored[spec.param] = spec.default
            self._effective[spec.param] = spec.default

    def _note_eeprom(self, key: str, ram_only: bool) -> None:
        """Before `key` changes: a RAM-only value keeps the EEPROM's to come back to at the
        next power cycle; any other write goes to EEPROM too."""
        if ram_only:
            self._eeprom.setdefault(key, self._stored[key])
        elif self._eeprom:
            self._eeprom.pop(key, None)

    def _commit(self, spec: ParamSpec, value: int, ram_only: bool = False) -> None:
        key = spec.param
        self._note_eeprom(key, ram_only or self.ram_only_now())
        old = self._stored[key]
        self._stored[key] = value
        if not spec.power_cycle:
            self._effective[key] = value
            self.version += 1
        if old != value:
            self._notify(key, value)
            if self.autosave and self.retained_path is not None and spec.retained:
                self.save()
        with self.ram_only_writes(ram_only):  # what a hook writes is kept as this write is
            for hook in list(self._write_hooks.get(key, ())):
                hook(key, old, value)

    def _notify(self, key: str, value: int) -> None:
        for fn in list(self._listeners):
            fn(key, value)
