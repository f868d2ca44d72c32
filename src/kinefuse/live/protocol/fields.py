"""Field kinds of the wire messages: how each value is encoded, and checked when decoded.

A hostile peer controls every byte, so decoding checks each field against its kind: Python type
(a bool is not an int, an int is accepted where a float is expected), string length and charset,
integer and float ranges, finiteness, and for arrays the wire dtype, the exact shape and the
byte count before anything is allocated. A check that fails raises
:class:`~kinefuse.live.protocol.wire_errors.FieldError` naming the message, the field and the
reason.

Arrays travel as a msgpack map ``{"dtype": "<f4", "shape": [25, 3], "data": <bytes>}``,
little-endian, C order (see docs/protocol.md, "Arrays").
"""

from __future__ import annotations

import math
import re
from abc import ABC, abstractmethod
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from kinefuse.core.camera.intrinsics import Intrinsics
from kinefuse.live.protocol.wire_errors import FieldError

#: integers on the wire are signed 64-bit
INT64_MAX = 2**63 - 1

#: an identifier, matched whole (``fullmatch``: no ``$`` that lets a trailing newline through)
_ID_RE = re.compile(r"[A-Za-z0-9_.:\-]+")


def printable(text: object, max_len: int = 300) -> str:
    """``text`` as it may reach a log or a terminal: every character that is not printable
    (control characters such as ESC or a newline, format characters such as a bidi override)
    shown as its Python escape (``\\x1b``, ``\\n``, ``\\u202e``), cut to ``max_len`` characters
    with ``...``. A peer's strings (ids, serials, reasons) go through it before they are logged,
    so a peer cannot clear a terminal or forge a log line."""
    s = str(text)
    if len(s) > max_len:
        s = s[:max_len] + "..."
    if s.isprintable():
        return s
    return "".join(c if c.isprintable() else c.encode("unicode_escape").decode("ascii") for c in s)


class Kind(ABC):
    """One field kind: ``encode(value)`` -> msgpack value, ``decode(raw, msg, name)`` -> value."""

    doc = ""

    def encode(self, value: Any) -> Any:
        return value

    @abstractmethod
    def decode(self, raw: Any, msg: str, name: str) -> Any:
        """The value of field ``name`` of message ``msg`` from its wire form (raises a
        field error naming both when it is not one)."""


@dataclass(frozen=True)
class Str(Kind):
    """A UTF-8 string of at most ``max_len`` characters (``ident``: ``[A-Za-z0-9_.:-]+``)."""

    max_len: int = 256
    ident: bool = False
    choices: tuple[str, ...] = ()
    allow_empty: bool = True

    @property
    def doc(self) -> str:  # type: ignore[override]
        if self.choices:
            return "str, one of " + ", ".join(repr(c) for c in self.choices)
        what = "identifier str" if self.ident else "str"
        return f"{what}, at most {self.max_len} chars" + ("" if self.allow_empty else ", not empty")

    def encode(self, value: Any) -> Any:
        return str(value)

    def decode(self, raw: Any, msg: str, name: str) -> str:
        if not isinstance(raw, str):
            raise FieldError(msg, name, f"expected a string, got {type(raw).__name__}")
        if len(raw) > self.max_len:
            raise FieldError(msg, name, f"{len(raw)} characters, at most {self.max_len} allowed")
        if not raw and not self.allow_empty:
            raise FieldError(msg, name, "must not be empty")
        if self.choices and raw not in self.choices:
            raise FieldError(msg, name, f"{raw!r} is not one of {', '.join(self.choices)}")
        if self.ident and raw and not _ID_RE.fullmatch(raw):
            raise FieldError(
                msg, name, f"{raw!r} has characters outside letters, digits and _ . : -"
            )
        return raw


@dataclass(frozen=True)
class Int(Kind):
    """An integer in ``[lo, hi]``."""

    lo: int = 0
    hi: int = INT64_MAX

    @property
    def doc(self) -> str:  # type: ignore[override]
        hi = "2**63-1" if self.hi == INT64_MAX else str(self.hi)
        return f"int in [{self.lo}, {hi}]"

    def encode(self, value: Any) -> Any:
        return int(value)

    def decode(self, raw: Any, msg: str, name: str) -> int:
        if isinstance(raw, bool) or not isinstance(raw, int):
            raise FieldError(msg, name, f"expected an integer, got {type(raw).__name__}")
        if not self.lo <= raw <= self.hi:
            raise FieldError(msg, name, f"{raw} is outside [{self.lo}, {self.hi}]")
        return raw


@dataclass(frozen=True)
class Float(Kind):
    """A float64 in ``[lo, hi]``; NaN only where ``allow_nan`` (never infinity)."""

    lo: float = -math.inf
    hi: float = math.inf
    allow_nan: bool = False

    @property
    def doc(self) -> str:  # type: ignore[override]
        rng = (
            "finite"
            if math.isinf(self.lo) and math.isinf(self.hi)
            else f"in [{self.lo:g}, {self.hi:g}]"
        )
        return f"float, {rng}" + (" or NaN" if self.allow_nan else "")

    def encode(self, value: Any) -> Any:
        return float(value)

    def decode(self, raw: Any, msg: str, name: str) -> float:
        if isinstance(raw, bool) or not isinstance(raw, int | float):
            raise FieldError(msg, name, f"expected a number, got {type(raw).__name__}")
        v = float(raw)
        if math.isnan(v):
            if self.allow_nan:
                return v
            raise FieldError(msg, name, "NaN is not allowed here")
        if math.isinf(v):
            raise FieldError(msg, name, "infinity is not allowed")
        if not self.lo <= v <= self.hi:
            raise FieldError(msg, name, f"{v} is outside [{self.lo}, {self.hi}]")
        return v


@dataclass(frozen=True)
class Bool(Kind):
    """``true`` or ``false`` (not 0/1)."""

    doc = "bool"

    def encode(self, value: Any) -> Any:
        return bool(value)

    def decode(self, raw: Any, msg: str, name: str) -> bool:
        if not isinstance(raw, bool):
            raise FieldError(msg, name, f"expected true or false, got {type(raw).__name__}")
        return raw


@dataclass(frozen=True)
class Bytes(Kind):
    """Raw bytes (msgpack bin) of a length in ``[min_len, max_len]``."""

    min_len: int = 0
    max_len: int = 1024

    @property
    def doc(self) -> str:  # type: ignore[override]
        if self.min_len == self.max_len:
            return f"bin, exactly {self.min_len} bytes"
        return f"bin, {self.min_len} to {self.max_len} bytes"

    def encode(self, value: Any) -> Any:
        return bytes(value)

    def decode(self, raw: Any, msg: str, name: str) -> bytes:
        if not isinstance(raw, bytes):
            raise FieldError(msg, name, f"expected bytes (msgpack bin), got {type(raw).__name__}")
        if not self.min_len <= len(raw) <= self.max_len:
            raise FieldError(
                msg, name, f"{len(raw)} bytes, expected {self.min_len} to {self.max_len}"
            )
        return raw


@dataclass(frozen=True)
class StrList(Kind):
    """A list of at most ``max_items`` strings of ``item`` kind (a tuple in Python)."""

    item: Str = Str(max_len=64, ident=True)
    max_items: int = 64

    @property
    def doc(self) -> str:  # type: ignore[override]
        return f"list of at most {self.max_items} {self.item.doc}"

    def encode(self, value: Any) -> Any:
        return [self.item.encode(v) for v in value]

    def decode(self, raw: Any, msg: str, name: str) -> tuple[str, ...]:
        if not isinstance(raw, list | tuple):
            raise FieldError(msg, name, f"expected a list, got {type(raw).__name__}")
        if len(raw) > self.max_items:
            raise FieldError(msg, name, f"{len(raw)} items, at most {self.max_items} allowed")
        return tuple(self.item.decode(v, msg, f"{name}[{i}]") for i, v in enumerate(raw))


@dataclass(frozen=True)
class Version(Kind):
    """A protocol version ``[major, minor]`` (two ints in [0, 65535]), a tuple in Python."""

    doc = "[major, minor], two ints in [0, 65535]"

    def encode(self, value: Any) -> Any:
        major, minor = value
        return [int(major), int(minor)]

    def decode(self, raw: Any, msg: str, name: str) -> tuple[int, int]:
        if not isinstance(raw, list | tuple) or len(raw) != 2:
            raise FieldError(msg, name, f"expected [major, minor], got {raw!r:.60}")
        part = Int(0, 65535)
        return (part.decode(raw[0], msg, name + "[0]"), part.decode(raw[1], msg, name + "[1]"))


_DTYPE_NAMES = {
    "<f4": "float32",
    "<f8": "float64",
    "<i8": "int64",
    "<i1": "int8",
    "|i1": "int8",
    "|u1": "uint8",
}


@dataclass(frozen=True)
class Array(Kind):
    """A numpy array of a fixed ``shape`` (``-1`` = any length up to ``max_len``).

    ``wire``: the dtype the encoder sends; ``accept``: the dtypes the decoder takes (the
    encoder's first); ``out``: the dtype of the decoded array. ``values``: ``"finite"``,
    ``"finite_or_nan"`` (NaN marks missing data; never infinity), ``"bool"`` (0/1 bytes) or
    ``"int"`` with ``lo``/``hi`` as the allowed range (also applied to finite float values).
    """

    shape: tuple[int, ...]
    wire: str = "<f8"
    accept: tuple[str, ...] = ("<f8", "<f4")
    out: str = "float64"
    values: str = "finite"
    lo: float = -math.inf
    hi: float = math.inf
    max_len: int = 64

    @property
    def doc(self) -> str:  # type: ignore[override]
        shape = ", ".join("n" if s == -1 else str(s) for s in self.shape)
        shape += "," if len(self.shape) == 1 else ""
        extra = {
            "finite": "finite",
            "finite_or_nan": "finite or NaN (missing)",
            "bool": "0 or 1",
            "int": f"in [{self.lo:g}, {self.hi:g}]",
        }[self.values]
        if self.values in ("finite", "finite_or_nan") and not math.isinf(self.lo):
            extra += f", within [{self.lo:g}, {self.hi:g}]"
        n = f", n <= {self.max_len}" if -1 in self.shape else ""
        wire = " or ".join(_DTYPE_NAMES[d] for d in self.accept)
        return f"array ({shape}{n}) {wire} on the wire, {extra}; {self.out} in Python"

    def encode(self, value: Any) -> Any:
        a = np.ascontiguousarray(value, dtype=np.dtype(self.wire))
        if a.ndim != len(self.shape) or any(
            s != -1 and s != n for s, n in zip(self.shape, a.shape, strict=True)
        ):
            raise ValueError(f"array of shape {a.shape} where {self.shape} is expected")
        return {"dtype": a.dtype.str, "shape": list(a.shape), "data": a.tobytes()}

    def decode(self, raw: Any, msg: str, name: str) -> np.ndarray:
        if not isinstance(raw, dict) or set(raw) != {"dtype", "shape", "data"}:
            raise FieldError(msg, name, "expected an array map {dtype, shape, data}")
        dt, shape, data = raw["dtype"], raw["shape"], raw["data"]
        if not isinstance(dt, str) or dt not in self.accept:
            raise FieldError(
                msg,
                name,
                f"dtype {dt!r:.20} not accepted, expected one of {', '.join(self.accept)}",
            )
        if (
            not isinstance(shape, list | tuple)
            or len(shape) != len(self.shape)
            or not all(isinstance(n, int) and not isinstance(n, bool) for n in shape)
        ):
            raise FieldError(msg, name, f"shape {shape!r:.40} is not {len(self.shape)} integers")
        for want, n in zip(self.shape, shape, strict=True):
            if (want == -1 and not 0 <= n <= self.max_len) or (want != -1 and n != want):
                expected = tuple("n" if s == -1 else s for s in self.shape)
                raise FieldError(msg, name, f"shape {tuple(shape)}, expected {expected}")
        dtype = np.dtype(dt)
        count = math.prod(shape)
        if not isinstance(data, bytes) or len(data) != count * dtype.itemsize:
            got = len(data) if isinstance(data, bytes) else type(data).__name__
            raise FieldError(
                msg,
                name,
                f"{got} data bytes for shape {tuple(shape)} of {dt} "
                f"(expected {count * dtype.itemsize})",
            )
        a = np.frombuffer(data, dtype=dtype).reshape(shape)
        self._check_values(a, msg, name)
        with np.errstate(invalid="ignore"):  # a signalling NaN (allowed as missing) stays NaN
            out = a.astype(np.dtype(self.out))
        out.flags.writeable = False
        return out

    def _check_values(self, a: np.ndarray, msg: str, name: str) -> None:
        # few numpy calls (a body frame's arrays are decoded 720 times a second with 24
        # sensors): a boolean array by its min and max, not a set test; a float one with one
        # isfinite pass, the exact NaN/infinity tests only for an array that is not all finite
        if not a.size:
            return
        if self.values == "bool":
            if a.min() < 0 or a.max() > 1:
                raise FieldError(msg, name, "a boolean array holds values other than 0 and 1")
            return
        v = a
        if a.dtype.kind == "f":
            finite = np.isfinite(a)
            if not finite.all():
                if np.isinf(a).any():
                    raise FieldError(msg, name, "holds infinity")
                if self.values != "finite_or_nan":
                    raise FieldError(msg, name, "holds NaN where finite values are required")
                v = a[finite]
        if v.size and (math.isfinite(self.lo) or math.isfinite(self.hi)):
            lo, hi = v.min(), v.max()
            if lo < self.lo or hi > self.hi:
                raise FieldError(
                    msg, name, f"values {lo:g}..{hi:g} leave [{self.lo:g}, {self.hi:g}]"
                )


@dataclass(frozen=True)
class Optional(Kind):
    """``nil`` or a value of ``inner`` kind."""

    inner: Kind

    @property
    def doc(self) -> str:  # type: ignore[override]
        return f"{self.inner.doc}; or nil"

    def encode(self, value: Any) -> Any:
        return None if value is None else self.inner.encode(value)

    def decode(self, raw: Any, msg: str, name: str) -> Any:
        return None if raw is None else self.inner.decode(raw, msg, name)


_INTRINSICS_FIELDS: dict[str, Kind] = {
    "width": Int(1, 16384),
    "height": Int(1, 16384),
    "fx": Float(1e-3, 1e6),
    "fy": Float(1e-3, 1e6),
    "cx": Float(-1e6, 1e6),
    "cy": Float(-1e6, 1e6),
    "min_range_m": Float(0.0, 1e3),
    "max_range_m": Float(0.0, 1e3),
}


@dataclass(frozen=True)
class IntrinsicsKind(Kind):
    """The depth camera's pinhole model: a map of :class:`~kinefuse.core.camera.Intrinsics`
    fields."""

    doc = (
        "map {width, height: int px; fx, fy, cx, cy: float px; min_range_m, max_range_m: "
        "float m} (Intrinsics)"
    )

    def encode(self, value: Any) -> Any:
        return value.to_dict()

    def decode(self, raw: Any, msg: str, name: str) -> Intrinsics:
        if not isinstance(raw, dict):
            raise FieldError(msg, name, f"expected a map, got {type(raw).__name__}")
        missing = [k for k in _INTRINSICS_FIELDS if k not in raw]
        if missing:
            raise FieldError(msg, name, f"missing {', '.join(missing)}")
        vals = {
            k: kind.decode(raw[k], msg, f"{name}.{k}") for k, kind in _INTRINSICS_FIELDS.items()
        }
        try:
            return Intrinsics.from_dict(vals)
        except ValueError as e:
            raise FieldError(msg, name, str(e)) from None


@dataclass(frozen=True)
class Records(Kind):
    """A list of at most ``max_items`` maps, each decoded by ``fields`` into ``make(**values)``.

    A missing :class:`Optional` field is left to ``make``'s default (a newer minor version may
    add one: an older peer does not send it); any other missing field is an error."""

    fields: tuple[tuple[str, Kind], ...]
    make: Callable[..., Any]
    max_items: int = 64
    label: str = "record"

    @property
    def doc(self) -> str:  # type: ignore[override]
        inner = "; ".join(f"{n}: {k.doc}" for n, k in self.fields)
        return f"list of at most {self.max_items} {self.label} maps {{{inner}}}"

    def encode(self, value: Any) -> Any:
        return [{n: k.encode(getattr(v, n)) for n, k in self.fields} for v in value]

    def decode(self, raw: Any, msg: str, name: str) -> tuple[Any, ...]:
        if not isinstance(raw, list | tuple):
            raise FieldError(msg, name, f"expected a list, got {type(raw).__name__}")
        if len(raw) > self.max_items:
            raise FieldError(msg, name, f"{len(raw)} items, at most {self.max_items} allowed")
        out = []
        for i, item in enumerate(raw):
            where = f"{name}[{i}]"
            if not isinstance(item, dict):
                raise FieldError(msg, where, f"expected a map, got {type(item).__name__}")
            vals = {}
            for n, k in self.fields:
                if n not in item:
                    if isinstance(k, Optional):
                        continue
                    raise FieldError(msg, f"{where}.{n}", "missing")
                vals[n] = k.decode(item[n], msg, f"{where}.{n}")
            out.append(self.make(**vals))
        return tuple(out)


def field_names(kinds: Sequence[tuple[str, Kind]]) -> list[str]:
    return [n for n, _ in kinds]
