"""The read-only attributes that :class:`tcd.engine.Denoiser` and :class:`tcd.engine.Prior` take from their
native object.

``num_features = NativeAttribute(int, "K = num_joints * 3.")`` in a class body is the attribute
``self._native.num_features``, read-only (assigning it raises ``AttributeError``), typed ``int`` for type
checkers (``__get__`` returns the type given) and listed with its type and text by ``help()`` under "Data
descriptors". One declaration per attribute instead of a hand-written property that forwards it.
"""
from __future__ import annotations

from typing import Any, Generic, Optional, Type, TypeVar, overload

T = TypeVar("T")


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
