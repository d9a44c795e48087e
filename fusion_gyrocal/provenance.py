"""What a result was computed from: :class:`Provenance`, carried by every result and written in every result file.

A calibration read back months later has to say which recordings, topics, columns and units it came from, with
which options and which version of the library, and how many samples were masked (saturated, non-finite) or
rejected (flex / outlier gate). :class:`Provenance` holds exactly that, one :class:`InputRecord` per gyro
(numbered from 1, gyro 1 the reference, as every message of the library numbers them), and round-trips through
JSON (:meth:`Provenance.to_dict`, :meth:`Provenance.from_dict`).
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Any

from .errors import FormatError


def _plain(v):
    """A value as JSON has it: tuples as lists, numpy scalars as Python numbers."""
    if isinstance(v, (tuple, list)):
        return [_plain(x) for x in v]
    if hasattr(v, "item") and not isinstance(v, (str, bytes)):
        return v.item()
    return v


@dataclass(frozen=True)
class InputRecord:
    """One gyro's recording as it was read.

    Attributes
    ----------
    gyro : int
        Gyro number, from 1 (gyro 1 is the reference).
    path : str
        The file or folder as given.
    format : str
        The detected format (``"csv"``, ``"euroc"``, ``"xsens"``, ``"npz"``, ``"bag"``, ...).
    reader_options : tuple of (str, value)
        The reader keywords used (``topic``, ``imu``, ``columns``, ``unit``, ``time_unit``, ...).
    unit_in : str
        The rate unit of the file before conversion to rad/s.
    rate_hz : float
        Its sample rate as read (Hz).
    n_samples : int
        Samples read.
    n_masked : int
        Samples masked by the reader (non-finite, saturated).
    source : str
        The reader's own description (path plus topic or IMU index).
    """

    gyro: int
    path: str
    format: str = ""
    reader_options: tuple = ()
    unit_in: str = "rad/s"
    rate_hz: float = float("nan")
    n_samples: int = 0
    n_masked: int = 0
    source: str = ""

    def __post_init__(self):
        object.__setattr__(self, "reader_options", tuple((str(k), _plain(v)) for k, v in self.reader_options))

    def to_dict(self) -> dict[str, Any]:
        d = {f.name: _plain(getattr(self, f.name)) for f in fields(self)}
        d["reader_options"] = {k: v for k, v in self.reader_options}
        return d

    @classmethod
    def from_dict(cls, d: dict) -> "InputRecord":
        kw = {f.name: d[f.name] for f in fields(cls) if f.name in d}
        kw["reader_options"] = tuple(dict(d.get("reader_options") or {}).items())
        return cls(**kw)


@dataclass(frozen=True)
class Provenance:
    """Inputs, options, version and sample counts of one result.

    Attributes
    ----------
    version : str
        ``fusion_gyrocal.__version__`` of the run.
    command : str
        The command line (empty for a call from Python).
    inputs : tuple of InputRecord
        One per gyro, gyro 1 first.
    options : tuple of (str, value)
        The options that differ from their defaults (:meth:`fusion_gyrocal.options.Options.to_dict`).
    n_used : int
        Samples the solve used.
    n_rejected : int
        Valid samples the flex / outlier gate rejected (0 where no gate ran).
    created_utc : str
        When the result was computed (ISO 8601, UTC).
    """

    version: str
    command: str = ""
    inputs: tuple = ()
    options: tuple = ()
    n_used: int = 0
    n_rejected: int = 0
    created_utc: str = ""

    def __post_init__(self):
        object.__setattr__(self, "inputs", tuple(self.inputs))
        object.__setattr__(self, "options", tuple((str(k), _plain(v)) for k, v in self.options))

    @property
    def n_masked(self) -> tuple:
        """Masked samples per gyro (gyro 1 first)."""
        return tuple(r.n_masked for r in self.inputs)

    def lines(self) -> list[str]:
        """What a person reads under a result: one line per input, one for the options and counts."""
        out = []
        for r in self.inputs:
            opts = ", ".join(f"{k} {v}" for k, v in r.reader_options)
            out.append(f"gyro {r.gyro}: {r.path} ({r.format}{', ' + opts if opts else ''}; read in {r.unit_in}, "
                       f"{r.rate_hz:.6g} Hz, {r.n_samples} samples, {r.n_masked} masked)")
        opts = ", ".join(f"{k}={v}" for k, v in self.options) or "defaults"
        out.append(f"fusion_gyrocal {self.version}; options: {opts}; samples used {self.n_used}, "
                   f"rejected {self.n_rejected}")
        return out

    def to_dict(self) -> dict[str, Any]:
        return {"version": self.version, "command": self.command, "created_utc": self.created_utc,
                "inputs": [r.to_dict() for r in self.inputs], "options": {k: v for k, v in self.options},
                "n_used": int(self.n_used), "n_rejected": int(self.n_rejected),
                "n_masked": list(self.n_masked)}

    @classmethod
    def from_dict(cls, d: dict) -> "Provenance":
        """Inverse of :meth:`to_dict`.

        Raises
        ------
        FormatError
            Not a mapping, or no ``version``.
        """
        if not isinstance(d, dict) or "version" not in d:
            raise FormatError(f"provenance: expected an object with a 'version', got {type(d).__name__}")
        return cls(version=str(d["version"]), command=str(d.get("command", "")),
                   inputs=tuple(InputRecord.from_dict(r) for r in d.get("inputs", ())),
                   options=tuple(dict(d.get("options") or {}).items()), n_used=int(d.get("n_used", 0)),
                   n_rejected=int(d.get("n_rejected", 0)), created_utc=str(d.get("created_utc", "")))


def command_line() -> str:
    """The running ``gyrocal`` command line, quoted as a shell would take it back."""
    import shlex
    import sys

    return " ".join(shlex.quote(a) for a in ["gyrocal", *sys.argv[1:]])


def provenance_of(streams, options=None, *, paths=None, formats=None, reader_options=None, command: str = "",
                  n_used: int = 0, n_rejected: int = 0) -> Provenance:
    """The :class:`Provenance` of a run on ``streams`` (:class:`~fusion_gyrocal.io.ImuStream`, gyro 1 first).

    ``paths``, ``formats`` and ``reader_options`` (one per stream) default to the streams' own ``source``;
    ``options`` is an :class:`~fusion_gyrocal.options.Options` (its non-default values are kept).
    """
    import datetime

    from . import __version__

    n = len(streams)
    paths = list(paths) if paths is not None else [s.source or s.name for s in streams]
    formats = list(formats) if formats is not None else [""] * n
    reader_options = list(reader_options) if reader_options is not None else [{}] * n
    inputs = tuple(InputRecord(gyro=k + 1, path=str(paths[k]), format=formats[k],
                               reader_options=tuple(dict(reader_options[k]).items()), unit_in=s.unit_in,
                               rate_hz=float(s.rate_hz), n_samples=int(len(s.t)),
                               n_masked=int(len(s.t) - int(s.valid.sum())), source=s.source)
                   for k, s in enumerate(streams))
    opts = tuple(options.to_dict().items()) if options is not None else ()
    now = datetime.datetime.now(datetime.timezone.utc).replace(microsecond=0).isoformat()
    return Provenance(version=__version__, command=command, inputs=inputs, options=opts, n_used=int(n_used),
                      n_rejected=int(n_rejected), created_utc=now)
