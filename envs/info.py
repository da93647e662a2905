"""``LazyInfo``: a step's ``info`` dict whose entries are made when first used.

Why: Gymnasium requires ``info`` to be a ``dict``, and making a single env's entries (array views
of the step's report row, the encoder counts as integers, the reward terms) costs about 1 µs, as
much as Chipmunk's step of the robot; most training loops never read them. A :class:`LazyInfo`
holds a function that makes them and calls it at the first dict operation of any kind, after
which it is the plain dict that function returned, so ``info["true_pose"]``, ``in``, iteration,
``len``, ``==``, ``repr``, ``copy``, ``dict(info)``, ``{**info}``, ``json.dumps`` and pickling
read exactly what an eagerly made dict would (a pickled or copied one is a plain ``dict``).

The one difference: code that bypasses the dict's methods and reads its C storage directly
(``dict.__getitem__(info, key)``, a C serialiser that walks dict subclasses itself) sees it
empty until some method has been called.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from _collections_abc import dict_items, dict_keys, dict_values

__all__ = ["LazyInfo"]


class LazyInfo(dict[str, Any]):
    """A dict whose entries ``make()`` returns, made at the first operation on it.

    Args:
        make: returns the entries; called at most once. It must not depend on state that
            changes after the step (take copies of such state when the step ends).
    """

    __slots__ = ("_make",)

    def __init__(self, make: Callable[[], dict[str, Any]]) -> None:
        super().__init__()
        self._make: Callable[[], dict[str, Any]] | None = make

    def _filled(self) -> LazyInfo:
        """Make the entries if not made yet; returns self."""
        make = self._make
        if make is not None:
            self._make = None
            dict.update(self, make())
        return self

    # Reading.
    def __getitem__(self, key: str) -> Any:
        return dict.__getitem__(self._filled(), key)

    def __contains__(self, key: object) -> bool:
        return dict.__contains__(self._filled(), key)

    def __iter__(self) -> Iterator[str]:
        return dict.__iter__(self._filled())

    def __reversed__(self) -> Iterator[str]:
        return dict.__reversed__(self._filled())

    def __len__(self) -> int:
        return dict.__len__(self._filled())

    def __repr__(self) -> str:
        return dict.__repr__(self._filled())

    def __eq__(self, other: object) -> bool:
        if isinstance(other, LazyInfo):
            other._filled()
        return dict.__eq__(self._filled(), other)

    def __ne__(self, other: object) -> bool:
        return not self == other

    __hash__ = None  # unhashable, as dict

    def keys(self) -> dict_keys[str, Any]:
        return dict.keys(self._filled())

    def values(self) -> dict_values[str, Any]:
        return dict.values(self._filled())

    def items(self) -> dict_items[str, Any]:
        return dict.items(self._filled())

    def get(self, key: str, default: Any = None) -> Any:
        return dict.get(self._filled(), key, default)

    def copy(self) -> dict[str, Any]:
        return dict(self.items())

    def __or__(self, other: dict[str, Any]) -> dict[str, Any]:  # type: ignore[override]
        return dict(self.items()) | other

    def __ror__(self, other: dict[str, Any]) -> dict[str, Any]:  # type: ignore[override]
        return other | dict(self.items())

    def __reduce__(self) -> tuple[type[dict[str, Any]], tuple[dict[str, Any]]]:
        return dict, (dict(self.items()),)

    # Writing (a wrapper adding an entry, e.g. RecordEpisodeStatistics' "episode").
    def __setitem__(self, key: str, value: Any) -> None:
        dict.__setitem__(self._filled(), key, value)

    def __delitem__(self, key: str) -> None:
        dict.__delitem__(self._filled(), key)

    def __ior__(self, other: Any) -> LazyInfo:  # type: ignore[override,misc]
        dict.update(self._filled(), other)
        return self

    def update(self, *args: Any, **kwargs: Any) -> None:
        dict.update(self._filled(), *args, **kwargs)

    def setdefault(self, key: str, default: Any = None) -> Any:
        return dict.setdefault(self._filled(), key, default)

    def pop(self, key: str, *default: Any) -> Any:
        return dict.pop(self._filled(), key, *default)

    def popitem(self) -> tuple[str, Any]:
        return dict.popitem(self._filled())

    def clear(self) -> None:
        self._make = None
        dict.clear(self)
