"""The read-only attributes that :class:`tcd.engine.Denoiser`, :class:`tcd.engine.Prior` and
:class:`tcd.engine.Generator` take from their native object, and :class:`NativeModel`, what else the three classes
share.

``num_features = NativeAttribute(int, "K = num_joints * 3.")`` in a class body is the attribute
``self._native.num_features``, read-only (assigning it raises ``AttributeError``), typed ``int`` for type
checkers (``__get__`` returns the type given) and listed with its type and text by ``help()`` under "Data
descriptors". One declaration per attribute instead of a hand-written property that forwards it.
"""

from __future__ import annotations

import copy
import json
import os
from typing import Any, ClassVar, Dict, Generic, Optional, Protocol, Type, TypeVar, Union, overload

T = TypeVar("T")


class _NativeFile(Protocol):
    """What :class:`NativeModel` reads of its native object itself (the rest through :class:`NativeAttribute`)."""

    @property
    def config_json(self) -> str: ...


N = TypeVar("N", bound=_NativeFile)
M = TypeVar("M", bound="NativeModel[Any]")

PathLike = Union[str, "os.PathLike[str]"]


class NativeAttribute(Generic[T]):
    """The attribute of the same name of the owner's ``_native`` object, read-only."""

    def __init__(self, kind: Type[T], doc: str = "") -> None:
        self.kind = kind
        self.name = ""
        self.__doc__ = f"{kind.__name__}: {doc}" if doc else kind.__name__

    def __set_name__(self, owner: type, name: str) -> None:
        self.name = name

    @overload
    def __get__(self, obj: None, owner: Optional[type] = None) -> "NativeAttribute[T]": ...

    @overload
    def __get__(self, obj: object, owner: Optional[type] = None) -> T: ...

    def __get__(self, obj: Any, owner: Optional[type] = None) -> Any:
        if obj is None:
            return self
        return getattr(obj._native, self.name)

    def __set__(self, obj: Any, value: Any) -> None:
        # defined (raising) so that the attribute is a data descriptor: read-only, and documented by help()
        raise AttributeError(f"{type(obj).__name__}.{self.name} is read-only")


class NativeModel(Generic[N]):
    """A loaded weight file: the engine's object ``_native`` (of the class ``_NATIVE``: ``N``) and its parsed
    ``tcd_config``; the base of :class:`tcd.engine.Denoiser`, :class:`tcd.engine.Prior` and
    :class:`tcd.engine.Generator`, with what they have alike."""

    __slots__ = ("_native", "_config")
    #: The engine's class of the file (``_native.Denoiser``, ``_native.Prior``, ``_native.Generator``).
    _NATIVE: ClassVar[Any]

    def __init__(self, native: N) -> None:
        if not isinstance(native, self._NATIVE):
            name = type(self).__name__
            raise TypeError(f"use {name}.load(path) or {name}.from_bytes(data)")
        self._native: N = native
        self._config: Dict[str, Any] = json.loads(native.config_json)

    @classmethod
    def load(cls: Type[M], path: PathLike) -> M:
        """Loads and validates a weight file of this class's kind (its ``role``). Missing file:
        ``FileNotFoundError``; invalid content, a file of another kind included:
        :class:`tcd.exceptions.WeightsError`."""
        return cls(cls._NATIVE.load(os.fspath(path)))

    @classmethod
    def from_bytes(cls: Type[M], data: bytes, name: str = "<bytes>") -> M:
        """Like :meth:`load`, from the bytes of a weight file; ``name`` appears in error messages."""
        return cls(cls._NATIVE.from_bytes(bytes(data), name))

    # ------------------------------------------------------------------ configuration
    @property
    def config(self) -> Dict[str, Any]:
        """The ``tcd_config`` JSON of the file, parsed (a fresh copy)."""
        return json.loads(json.dumps(self._config))

    def _section(self, name: str) -> Dict[str, Any]:
        """One top-level block of :attr:`config` (``{}`` where absent), a fresh copy of that block alone: the
        calls that read ``data`` per call (the frame rate, the joint names) need not copy the whole config."""
        return copy.deepcopy(self._config.get(name) or {})

    # The file's settings, read from the engine's model (each read-only); each class adds its own.
    path = NativeAttribute(str, "The weight file's path (or the name given to :meth:`from_bytes`).")
    num_features = NativeAttribute(int, "K = num_joints * 3.")
    num_joints = NativeAttribute(int, "Joints of the model (its config's ``model.num_joints``).")
    kernel = NativeAttribute(
        str,
        'The compute kernels in use: ``"portable"``, ``"avx2"`` or ``"avx512"`` (chosen '
        "when the file is loaded: ``$TCD_KERNEL``, default the best this CPU supports, see "
        ":func:`tcd.engine.supported_kernels`).",
    )

    def __repr__(self) -> str:
        return repr(self._native)
