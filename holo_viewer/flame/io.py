"""Reading and writing FLAME-format model files (chumpy-free).

Two formats hold the same keys (docs/design.md section 4):

* FLAME 2020 / 2023 ``.pkl`` as distributed. FLAME 2020 stores ``shapedirs`` as a
  chumpy ``Ch`` object and ``J_regressor`` as a scipy sparse matrix. We unpickle
  with ``encoding='latin1'`` and a restricted :class:`pickle.Unpickler` that maps
  every ``chumpy.*`` class to a stub capturing the pickled state (a ``Ch`` pickles
  its ``__dict__``, whose ``'x'`` entry is the ndarray); chumpy is never imported.
  Only an exact allow-list of (module, name) pairs resolves (numpy's array
  reconstructors and dtype, the scipy.sparse csc/csr/coo classes, a few builtin
  types); every other reference is refused before anything is imported, so a
  pickle cannot run code, open files or import modules through this loader.
* Our ``.npz`` (no pickled objects) with the same keys plus extra metadata keys.

Required keys and sizes (V vertices, J = 5 joints, K blend shapes, F faces)::

    v_template (V, 3)   shapedirs (V, 3, K)   posedirs (V, 3, 9 (J - 1))
    J_regressor (J, V)  weights (V, J)        kintree_table (2, J)   f (F, 3), 0 <= f < V

Every other key is passed through as metadata.
"""

from __future__ import annotations

import builtins
import collections
import io
import os
import pickle
import struct
import zipfile
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from ..errors import FlameError, InputError
from ..fileio import atomic_write, read_limited
from ..validation import check_array

__all__ = ["REQUIRED_KEYS", "N_JOINTS", "load_flame_arrays", "save_flame_npz", "validate_flame_arrays",
           "ChumpyStub", "SparseStub", "MAX_PICKLE_BYTES", "LOAD_BUDGET_BYTES", "MAX_DENSE_ELEMENTS", "MAX_NESTING"]

REQUIRED_KEYS = ("v_template", "shapedirs", "posedirs", "J_regressor", "weights", "kintree_table", "f")
N_JOINTS = 5


# --------------------------------------------------------------------------- pickle

#: largest FLAME pickle read (FLAME 2020 is ~50 MB, FLAME 2023 ~100 MB); the file is read whole first
MAX_PICKLE_BYTES = 256 << 20
#: bytes the pickle's own calls may allocate beyond the file's bytes (``bytearray(n)``, array
#: reconstruction, containers built from iterables): a 65-byte pickle cannot ask for gigabytes
LOAD_BUDGET_BYTES = 768 << 20
#: elements of one dense array built from a pickled sparse matrix (256 MiB of float64; FLAME's
#: largest array, ``shapedirs``, has 6 M)
MAX_DENSE_ELEMENTS = 1 << 25
#: container nesting (FLAME needs 4: dict, state tuple, shape tuple); deeper data overflows
#: C recursion in hashing, repr and numpy's conversion
MAX_NESTING = 64
#: objects a pickled value expands to when shared containers are counted every time they appear
MAX_TREE_OBJECTS = 10_000_000


class ChumpyStub:
    """Stand-in for any ``chumpy`` class met while unpickling.

    Captures constructor arguments and the pickled state; :meth:`to_array`
    recovers the ndarray a plain ``Ch`` holds.
    """

    chumpy_name = "chumpy.Ch"

    def __new__(cls, *args: Any, **kwargs: Any) -> "ChumpyStub":
        obj = super().__new__(cls)
        obj._args = args
        obj._state = None
        return obj

    def __init__(self, *args: Any, **kwargs: Any) -> None:  # state arrives via __setstate__
        pass

    def __setstate__(self, state: Any) -> None:
        self._state = state

    def to_array(self, key: str, source: str) -> np.ndarray:
        """The ndarray held by the pickled object (its ``x`` term, or its only array)."""
        state = self._state
        if isinstance(state, tuple) and len(state) == 2 and isinstance(state[0], dict):
            state = state[0]  # (dict, slotstate)
        if isinstance(state, dict):
            if "x" in state:
                return _plain_array(state["x"], key, source)
            arrays = [v for v in state.values() if isinstance(v, (np.ndarray, ChumpyStub))]
            if len(arrays) == 1:
                return _plain_array(arrays[0], key, source)
        elif isinstance(state, (np.ndarray, ChumpyStub)):
            return _plain_array(state, key, source)
        if len(self._args) == 1 and isinstance(self._args[0], np.ndarray):
            return self._args[0]
        raise FlameError(f"{source}: {key}: a pickled {self.chumpy_name} object without a stored array "
                         f"(expected a plain chumpy Ch holding an ndarray in its 'x' term)")


class SparseStub:
    """Captured state of a pickled scipy sparse matrix; scipy never sees it.

    scipy checks ``indptr``/``indices`` only in its constructor, and unpickling bypasses the
    constructor: its ``toarray`` then writes wherever the file's indices point. The loader
    keeps the state here, :func:`_sparse_to_dense` checks it and builds the dense array
    with numpy.
    """

    sparse_format = "csr"
    sparse_name = "scipy.sparse.csr_matrix"

    def __new__(cls, *args: Any, **kwargs: Any) -> "SparseStub":
        obj = super().__new__(cls)
        obj._state = None
        return obj

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        raise pickle.UnpicklingError(f"a pickle calls {self.sparse_name}(...); a pickled sparse matrix is "
                                     f"restored from its state, not built by a call")

    def __setstate__(self, state: Any) -> None:
        self._state = state


def _plain_array(value: Any, key: str, source: str) -> np.ndarray:
    if isinstance(value, ChumpyStub):
        return value.to_array(key, source)
    if isinstance(value, SparseStub):
        return _sparse_to_dense(value, key, source)
    if not isinstance(value, np.ndarray):
        raise FlameError(f"{source}: {key}: expected a numpy array (or a scipy sparse or chumpy array), "
                         f"found {type(value).__name__}")
    return value


def _numpy_core() -> Any:
    """numpy's core package (``numpy._core`` in numpy 2, ``numpy.core`` in 1.x); already imported."""
    core = getattr(np, "_core", None)
    return core if core is not None else np.core


def _is_latin1(encoding: Any) -> bool:
    return isinstance(encoding, str) and encoding.lower().replace("_", "-") in ("latin1", "latin-1", "iso-8859-1")


def _latin1_encode(text: Any, encoding: str = "latin1", errors: str = "strict") -> bytes:
    """``_codecs.encode`` as protocol 0-2 pickles use it for ``bytes``: latin-1 only.

    Any other codec is refused: a codec lookup imports ``encodings.<name>`` modules.
    """
    if not isinstance(text, str) or not _is_latin1(encoding):
        raise pickle.UnpicklingError(f"_codecs.encode with {encoding!r}: a FLAME pickle encodes bytes as latin1")
    return text.encode("latin1", errors)


_SPARSE_CLASSES = {"csc": ("csc_matrix", "csc_array"), "csr": ("csr_matrix", "csr_array"),
                   "coo": ("coo_matrix", "coo_array")}
_BUILTINS = ("object", "set", "frozenset", "list", "dict", "tuple", "int", "float", "complex", "bool", "str",
             "bytes", "bytearray", "slice")
#: builtin types a pickle may call with an argument that allocates or hashes: checked wrappers
_CHECKED_BUILTINS = ("set", "frozenset", "list", "dict", "tuple", "str", "bytes", "bytearray")
_SCALAR_KEYS = (str, bytes, int, float, complex, bool, type(None))


def _sparse_stub(fmt: str, name: str) -> type:
    return type(name, (SparseStub,), {"sparse_format": fmt, "sparse_name": f"scipy.sparse.{name}"})


_SPARSE_STUBS = {name: _sparse_stub(fmt, name) for fmt, names in _SPARSE_CLASSES.items() for name in names}


def _allowed_globals() -> dict[tuple[str, str], str]:
    """The exact (module, name) pairs a FLAME 2020/2023 pickle may reference -> what they resolve to.

    Written by Python 2 or 3, numpy 1.x or 2.x, scipy old (``scipy.sparse.csc``) or new
    (``scipy.sparse._csc``), pickle protocols 0 to 5. Nothing else resolves.
    """
    table: dict[tuple[str, str], str] = {}
    for core in ("numpy.core", "numpy._core"):
        table[(f"{core}.multiarray", "_reconstruct")] = "_reconstruct"
        table[(f"{core}.multiarray", "scalar")] = "scalar"
        table[(f"{core}.numeric", "_frombuffer")] = "_frombuffer"
    table[("numpy", "ndarray")] = "ndarray"
    table[("numpy", "dtype")] = "dtype"
    for fmt, names in _SPARSE_CLASSES.items():
        for name in names:
            for module in ("scipy.sparse", f"scipy.sparse.{fmt}", f"scipy.sparse._{fmt}"):
                table[(module, name)] = f"sparse:{name}"
    for module in ("builtins", "__builtin__"):
        for name in _BUILTINS:
            table[(module, name)] = f"builtin:{name}"
    for module in ("copyreg", "copy_reg"):
        table[(module, "_reconstructor")] = "_reconstructor"
    table[("_codecs", "encode")] = "encode"
    table[("collections", "OrderedDict")] = "builtin:OrderedDict"
    return table


_ALLOWED = _allowed_globals()


class _FlameUnpickler(pickle._Unpickler):  # type: ignore[name-defined]  # the pure-Python unpickler
    """Unpickler resolving only an exact allow-list of (module, name) pairs, under budgets.

    ``chumpy.*`` classes become :class:`ChumpyStub` subclasses and scipy sparse classes
    :class:`SparseStub` subclasses (scipy is never imported nor called); every other pair
    must be in ``_ALLOWED`` (numpy's array and scalar reconstructors and ``dtype``,
    ``copyreg._reconstructor``, latin-1 ``_codecs.encode``, ``OrderedDict`` and a few builtin
    types). The pair is checked before anything is imported, so a pickle can neither run
    code, open files, nor import a module with side effects.

    The pure-Python unpickler is used because its opcodes can be checked one by one and it
    reads a declared length from the in-memory file without allocating it first. Every call
    a pickle makes that could allocate (``bytearray(n)``, ``_reconstruct(ndarray, shape)``,
    ``list(iterable)``) is charged to :data:`LOAD_BUDGET_BYTES` before it runs; dict keys and
    set members must be flat (a key nested 200 000 deep overflows the C stack when hashed);
    arrays of Python objects and structured dtypes are refused. After loading,
    :func:`_check_nesting` bounds depth and expanded size.
    """

    dispatch = dict(pickle._Unpickler.dispatch)  # type: ignore[attr-defined]

    def __init__(self, fh: Any, source: str) -> None:
        super().__init__(fh, encoding="latin1")
        self._source = source
        self._budget = LOAD_BUDGET_BYTES
        core = _numpy_core()
        self._resolved: dict[str, Any] = {
            "_reconstruct": self._reconstruct, "scalar": self._scalar, "_frombuffer": self._frombuffer,
            "ndarray": np.ndarray, "dtype": self._dtype, "_reconstructor": self._reconstructor,
            "encode": _latin1_encode,
        }
        self._core = core

    @classmethod
    def loads(cls, data: bytes, source: str) -> Any:
        """Unpickle ``data`` (already read, at most :data:`MAX_PICKLE_BYTES`) and bound its nesting."""
        obj = cls(io.BytesIO(data), source).load()
        _check_nesting(obj, source)
        return obj

    # ---- what names resolve to

    def find_class(self, module: str, name: str) -> Any:
        if module == "chumpy" or module.startswith("chumpy."):
            if not name.isidentifier():
                raise FlameError(f"{self._source}: the pickle references a chumpy class named {name!r}; refusing "
                                 f"to load it")
            return type(name, (ChumpyStub,), {"chumpy_name": f"{module}.{name}"})
        what = _ALLOWED.get((module, name))
        if what is None:
            raise FlameError(f"{self._source}: the pickle references {module}.{name}; a FLAME model file holds "
                             f"only numpy arrays, scipy sparse matrices and chumpy arrays, refusing to load it")
        if what.startswith("sparse:"):
            return _SPARSE_STUBS[what[7:]]
        if what.startswith("builtin:"):
            tp = collections.OrderedDict if what == "builtin:OrderedDict" else getattr(builtins, what[8:])
            return self._checked(tp) if tp.__name__ in _CHECKED_BUILTINS + ("OrderedDict",) else tp
        return self._resolved[what]

    def persistent_load(self, pid: Any) -> Any:
        raise FlameError(f"{self._source}: the pickle uses persistent ids; a FLAME model file has none, "
                         f"refusing to load it")

    # ---- budgets and checks

    def _refuse(self, what: str) -> FlameError:
        return FlameError(f"{self._source}: {what}; refusing to load it")

    def _charge(self, n_bytes: int, what: str) -> None:
        """Take ``n_bytes`` from the load budget *before* allocating them."""
        if n_bytes > self._budget:
            raise self._refuse(f"{what} would allocate {n_bytes:,} bytes, over the loader's budget of "
                               f"{LOAD_BUDGET_BYTES:,} bytes (flame.io.LOAD_BUDGET_BYTES)")
        self._budget -= n_bytes

    def _check_keys(self, keys: Any) -> None:
        for key in keys:
            flat = isinstance(key, _SCALAR_KEYS) or (
                type(key) is tuple and len(key) <= 64 and all(isinstance(k, _SCALAR_KEYS) for k in key))
            if not flat:
                raise self._refuse(f"a dict key or set member of type {type(key).__name__} that is not a string, "
                                   f"bytes, number or flat tuple of them (a FLAME pickle's keys are strings)")

    def _checked_dtype(self, dtype: Any) -> np.dtype:
        dt = dtype if isinstance(dtype, np.dtype) else self._dtype(dtype)
        if dt.hasobject or dt.fields is not None or dt.subdtype is not None:
            raise self._refuse(f"an array of dtype {dt} (Python objects or a structured dtype); a FLAME model "
                               f"holds numeric and string arrays only")
        return dt

    def _checked(self, tp: type) -> Any:
        """``tp`` (a builtin container or text type) called only with budgeted, hash-safe arguments."""
        def call(*args: Any, **kwargs: Any) -> Any:
            if kwargs:
                raise self._refuse(f"a call of {tp.__name__} with keyword arguments")
            if tp in (bytes, bytearray, str) and len(args) >= 2:
                if not _is_latin1(args[1]):
                    raise self._refuse(f"{tp.__name__}(..., {args[1]!r}): only latin-1 text is decoded")
            elif tp in (bytes, bytearray) and args and isinstance(args[0], int):
                self._charge(int(args[0]), f"{tp.__name__}({args[0]})")
            elif tp is str and args and not isinstance(args[0], (str, bytes, int, float)):
                raise self._refuse(f"str() of a {type(args[0]).__name__}")
            if args and isinstance(args[0], (str, bytes, bytearray)):
                # list("...") makes one object per character: 64 bytes each, charged like any container
                per_item = 64 if tp in (list, tuple, set, frozenset) else 1
                self._charge(per_item * len(args[0]), f"{tp.__name__}() of {len(args[0])} characters")
            if args and not isinstance(args[0], (str, bytes, bytearray, int)):
                items = args[0]
                if not isinstance(items, (list, tuple, dict, set, frozenset, collections.OrderedDict)):
                    raise self._refuse(f"{tp.__name__}() of a {type(items).__name__}")
                self._charge(64 * len(items), f"{tp.__name__}() of {len(items)} items")
                if tp in (set, frozenset):
                    self._check_keys(items)
                elif tp in (dict, collections.OrderedDict) and not isinstance(items, dict):
                    pairs = list(items)
                    if not all(type(p) in (tuple, list) and len(p) == 2 for p in pairs):
                        raise self._refuse(f"{tp.__name__}() of items that are not (key, value) pairs")
                    self._check_keys(p[0] for p in pairs)
                elif isinstance(items, dict):
                    self._check_keys(items)
            return tp(*args)

        call.__name__ = tp.__name__
        return call

    # ---- numpy and copyreg entry points, checked

    def _dtype(self, spec: Any, align: Any = False, copy: Any = False) -> np.dtype:
        if not isinstance(spec, (str, bytes)) or not isinstance(align, (bool, int)) or not isinstance(copy, (bool, int)):
            raise self._refuse(f"numpy.dtype({spec!r}, ...): expected a type code such as 'f8'")
        try:
            dt = np.dtype(spec.decode("latin1") if isinstance(spec, bytes) else spec, align=bool(align),
                          copy=bool(copy))
        except TypeError as exc:
            raise pickle.UnpicklingError(f"numpy.dtype({spec!r}): {exc}") from exc
        return self._checked_dtype(dt)

    def _reconstruct(self, subtype: Any, shape: Any, dtype: Any) -> np.ndarray:
        if subtype is not np.ndarray:
            raise self._refuse(f"an array reconstructed as {getattr(subtype, '__name__', type(subtype).__name__)}")
        dims = shape if isinstance(shape, tuple) else (shape,)
        if not all(isinstance(d, int) and 0 <= d for d in dims) or len(dims) > 32:
            raise self._refuse(f"an array of shape {shape!r}")
        dt = self._checked_dtype(dtype)
        self._charge(int(np.prod(dims, dtype=object)) * dt.itemsize, f"an array of shape {dims} and dtype {dt}")
        return self._core.multiarray._reconstruct(subtype, dims, dt)

    def _scalar(self, dtype: Any, *args: Any) -> Any:
        return self._core.multiarray.scalar(self._checked_dtype(dtype), *args)

    def _frombuffer(self, buf: Any, dtype: Any, shape: Any, order: Any) -> np.ndarray:
        return self._core.numeric._frombuffer(buf, self._checked_dtype(dtype), shape, order)

    def _reconstructor(self, cls: Any, base: Any, state: Any) -> Any:
        if base is not object or not isinstance(cls, type) or not issubclass(cls, (ChumpyStub, SparseStub)):
            raise self._refuse(f"copyreg._reconstructor({getattr(cls, '__name__', cls)!r}, "
                               f"{getattr(base, '__name__', base)!r}, ...): only sparse and chumpy objects are "
                               f"restored this way")
        return object.__new__(cls)

    # ---- opcodes that call, hash or set state

    def _call(self, func: Any, args: Any) -> Any:
        plain = (object, int, float, complex, bool, slice)
        if isinstance(func, type) and not issubclass(func, (ChumpyStub, SparseStub)) and func not in plain:
            raise self._refuse(f"a call of {getattr(func, '__name__', func)!r}")
        if not isinstance(args, tuple):
            raise pickle.UnpicklingError(f"call arguments must be a tuple, found {type(args).__name__}")
        return func(*args)

    def load_reduce(self) -> None:
        args = self.stack.pop()
        self.stack[-1] = self._call(self.stack[-1], args)

    dispatch[pickle.REDUCE[0]] = load_reduce

    def load_newobj(self) -> None:
        args = self.stack.pop()
        cls = self.stack.pop()
        if not isinstance(cls, type) or not issubclass(cls, (ChumpyStub, SparseStub)):
            raise self._refuse(f"a new object of {getattr(cls, '__name__', cls)!r} (only sparse and chumpy "
                               f"objects are created this way)")
        self.append(cls.__new__(cls, *args))

    dispatch[pickle.NEWOBJ[0]] = load_newobj

    def load_newobj_ex(self) -> None:
        raise self._refuse("a NEWOBJ_EX opcode (keyword construction; FLAME pickles have none)")

    dispatch[pickle.NEWOBJ_EX[0]] = load_newobj_ex

    def load_setitem(self) -> None:
        self._check_keys((self.stack[-2],))
        super().load_setitem()

    dispatch[pickle.SETITEM[0]] = load_setitem

    def load_setitems(self) -> None:
        items = self.pop_mark()
        self._check_keys(items[0::2])
        target = self.stack[-1]
        for i in range(0, len(items), 2):
            target[items[i]] = items[i + 1]

    dispatch[pickle.SETITEMS[0]] = load_setitems

    def load_dict(self) -> None:
        items = self.pop_mark()
        self._check_keys(items[0::2])
        self.append({items[i]: items[i + 1] for i in range(0, len(items), 2)})

    dispatch[pickle.DICT[0]] = load_dict

    def load_additems(self) -> None:
        items = self.pop_mark()
        self._check_keys(items)
        target = self.stack[-1]
        if not isinstance(target, set):
            raise pickle.UnpicklingError(f"ADDITEMS on a {type(target).__name__}")
        target.update(items)

    dispatch[pickle.ADDITEMS[0]] = load_additems

    def load_frozenset(self) -> None:
        items = self.pop_mark()
        self._check_keys(items)
        self.append(frozenset(items))

    dispatch[pickle.FROZENSET[0]] = load_frozenset

    def load_build(self) -> None:
        state = self.stack[-1]
        inst = self.stack[-2]
        if isinstance(inst, np.ndarray):
            if not (isinstance(state, tuple) and len(state) in (4, 5)):
                raise pickle.UnpicklingError(f"array state: expected a 4 or 5-tuple, found {type(state).__name__}")
            self._checked_dtype(state[-3])
            if not isinstance(state[-1], (bytes, bytearray)):
                raise self._refuse(f"array data of type {type(state[-1]).__name__} (arrays of Python objects)")
        elif isinstance(inst, np.dtype):
            if not (isinstance(state, tuple) and all(isinstance(s, (str, bytes, int, type(None))) for s in state)):
                raise self._refuse("a structured or sub-array dtype; a FLAME model holds plain numeric arrays")
        elif not isinstance(inst, (ChumpyStub, SparseStub)):
            raise self._refuse(f"object state set on a {type(inst).__name__}")
        super().load_build()

    dispatch[pickle.BUILD[0]] = load_build

    for _op in (pickle.INST, pickle.OBJ, pickle.EXT1, pickle.EXT2, pickle.EXT4):
        dispatch.pop(_op[0], None)  # unknown opcode -> UnpicklingError (FLAME pickles have none)
    del _op


def _children(obj: Any) -> tuple | None:
    """Contained objects the nesting check follows, or ``None`` for a leaf."""
    if isinstance(obj, (list, tuple, set, frozenset)):
        return tuple(obj)
    if isinstance(obj, dict):
        return tuple(obj.keys()) + tuple(obj.values())
    if isinstance(obj, (ChumpyStub, SparseStub)):
        return (obj._state, getattr(obj, "_args", ()))
    return None


def _check_nesting(root: Any, source: str) -> None:
    """Refuse data nested deeper than :data:`MAX_NESTING`, cyclic, or expanding to too many objects.

    Iterative (no recursion) over the object graph, each shared object once; ``size``
    counts an object every time it appears (``[L, L]`` with ``L`` nested 40 deep is 2**40).
    """
    height: dict[int, int] = {}
    size: dict[int, int] = {}
    path: set[int] = set()
    stack: list[tuple[Any, bool]] = [(root, False)]
    while stack:
        obj, finished = stack.pop()
        kids = _children(obj)
        if kids is None:
            continue
        oid = id(obj)
        if finished:
            path.discard(oid)
            height[oid] = 1 + max((height.get(id(k), 0) for k in kids), default=0)
            size[oid] = 1 + sum(size.get(id(k), 1) for k in kids)
            if size[oid] > MAX_TREE_OBJECTS:
                raise FlameError(f"{source}: a pickled value expands to more than {MAX_TREE_OBJECTS:,} objects "
                                 f"(shared containers repeated); refusing to load it")
            continue
        if oid in height:
            continue
        if oid in path:
            raise FlameError(f"{source}: a pickled container contains itself (a cycle); refusing to load it")
        path.add(oid)
        if len(path) > MAX_NESTING:
            raise FlameError(f"{source}: data nested deeper than {MAX_NESTING} levels (a FLAME model needs 4); "
                             f"refusing to load it")
        stack.append((obj, True))
        stack.extend((k, False) for k in kids if id(k) not in height)


def _as_int_array(value: Any, name: str, key: str, source: str) -> np.ndarray:
    if not isinstance(value, np.ndarray) or value.ndim != 1 or not np.issubdtype(value.dtype, np.integer):
        found = (f"shape {value.shape}, dtype {value.dtype}" if isinstance(value, np.ndarray)
                 else type(value).__name__)
        raise FlameError(f"{source}: {key}: sparse {name}: expected a 1-D integer array, found {found}")
    return value.astype(np.int64)


def _sparse_to_dense(stub: SparseStub, key: str, source: str) -> np.ndarray:
    """Check a pickled sparse matrix's state and build its dense float64 array.

    ``indptr`` starts at 0, never decreases and ends at nnz; ``indices`` (csr/csc) or
    ``row``/``col`` (coo) lie inside the shape; ``data`` is real and as long as the indices;
    the dense size is budgeted (:data:`MAX_DENSE_ELEMENTS`) before anything is allocated.
    Duplicate entries are summed, as scipy does.
    """
    what = f"{source}: {key}: {stub.sparse_name}"
    state = stub._state
    if isinstance(state, tuple) and len(state) == 2 and isinstance(state[0], dict):
        state = state[0]
    if not isinstance(state, dict):
        raise FlameError(f"{what}: expected its pickled state as a dict, found {type(state).__name__}")
    shape = state.get("_shape", state.get("shape"))
    if not (isinstance(shape, tuple) and len(shape) == 2
            and all(isinstance(s, (int, np.integer)) and not isinstance(s, bool) and s >= 0 for s in shape)):
        raise FlameError(f"{what}: expected a shape of two non-negative integers, found {shape!r}")
    n_rows, n_cols = int(shape[0]), int(shape[1])
    if n_rows * n_cols > MAX_DENSE_ELEMENTS:
        raise FlameError(f"{what}: shape {(n_rows, n_cols)} would allocate {n_rows * n_cols:,} dense elements, over "
                         f"the budget of {MAX_DENSE_ELEMENTS:,} (flame.io.MAX_DENSE_ELEMENTS)")
    data = state.get("data")
    if not isinstance(data, np.ndarray) or data.ndim != 1 or not (
            np.issubdtype(data.dtype, np.floating) or np.issubdtype(data.dtype, np.integer)):
        found = f"shape {data.shape}, dtype {data.dtype}" if isinstance(data, np.ndarray) else type(data).__name__
        raise FlameError(f"{what}: data: expected a 1-D real array, found {found}")
    if stub.sparse_format == "coo":
        coords = state.get("coords", (state.get("row"), state.get("col")))
        if not (isinstance(coords, tuple) and len(coords) == 2):
            raise FlameError(f"{what}: expected (row, col) coordinates, found {type(coords).__name__}")
        rows = _as_int_array(coords[0], "row", key, source)
        cols = _as_int_array(coords[1], "col", key, source)
        if not rows.size == cols.size == data.size:
            raise FlameError(f"{what}: expected row, col and data of one length, found {rows.size}, {cols.size}, "
                             f"{data.size}")
    else:
        n_major, n_minor = (n_rows, n_cols) if stub.sparse_format == "csr" else (n_cols, n_rows)
        indptr = _as_int_array(state.get("indptr"), "indptr", key, source)
        indices = _as_int_array(state.get("indices"), "indices", key, source)
        if indptr.size != n_major + 1:
            raise FlameError(f"{what}: indptr: expected length {n_major + 1} for shape {(n_rows, n_cols)}, "
                             f"found {indptr.size}")
        if indptr[0] != 0:
            raise FlameError(f"{what}: indptr: expected to start at 0, found {indptr[0]}")
        if np.any(np.diff(indptr) < 0):
            raise FlameError(f"{what}: indptr: expected non-decreasing offsets, found {indptr[:8].tolist()}...")
        nnz = int(indptr[-1])
        if indices.size != nnz:
            raise FlameError(f"{what}: indptr ends at nnz = {nnz}, but indices has {indices.size} entries")
        if data.size != nnz:
            raise FlameError(f"{what}: data: expected nnz = {nnz} values, found {data.size}")
        major = np.repeat(np.arange(n_major, dtype=np.int64), np.diff(indptr))
        rows, cols = (major, indices) if stub.sparse_format == "csr" else (indices, major)
    for name, idx, bound in (("row", rows, n_rows), ("column", cols, n_cols)):
        if idx.size and (idx.min() < 0 or idx.max() >= bound):
            bad = int(idx.min()) if idx.min() < 0 else int(idx.max())
            label = "indices" if stub.sparse_format != "coo" else ("row" if name == "row" else "col")
            raise FlameError(f"{what}: {label}: expected {name} indices in [0, {bound}), found {bad}")
    return _build_dense((n_rows, n_cols), rows, cols, data)


def _build_dense(shape: tuple[int, int], rows: np.ndarray, cols: np.ndarray, data: np.ndarray) -> np.ndarray:
    """The dense float64 array of checked coordinates (duplicates summed)."""
    out = np.zeros(shape, dtype=np.float64)
    np.add.at(out, (rows, cols), data.astype(np.float64))
    return out


def _load_pkl(path: Path) -> dict[str, Any]:
    source = str(path)
    try:
        raw = read_limited(path, MAX_PICKLE_BYTES, FlameError, "a FLAME pickle")
        data = _FlameUnpickler.loads(raw, source)
    except FlameError:
        raise
    except FileNotFoundError as exc:
        raise FlameError(f"{source}: file not found") from exc
    except IsADirectoryError as exc:
        raise FlameError(f"{source}: expected a FLAME .pkl or .npz file, found a directory") from exc
    except (pickle.UnpicklingError, EOFError, ValueError, TypeError, AttributeError, IndexError, KeyError,
            ImportError, MemoryError, UnicodeDecodeError, OSError, RecursionError, struct.error) as exc:
        raise FlameError(f"{source}: not a readable FLAME pickle ({type(exc).__name__}: {exc})") from exc
    if not isinstance(data, dict):
        raise FlameError(f"{source}: expected a pickled dict of FLAME arrays, found {type(data).__name__}")
    out: dict[str, Any] = {}
    for key, value in data.items():
        key = key.decode("latin1") if isinstance(key, bytes) else str(key)
        if isinstance(value, (ChumpyStub, SparseStub)) or key in REQUIRED_KEYS:
            value = _plain_array(value, key, source)
        out[key] = value
    return out


def _load_npz(path: Path) -> dict[str, Any]:
    from ..fileio import read_npz

    try:
        return read_npz(path, FlameError, "FLAME .npz model")  # budgeted: a deflate bomb is refused unread
    except FlameError as exc:
        raise FlameError(str(exc).replace("cannot read FLAME .npz model", "not a readable .npz file", 1)) from None


def load_flame_arrays(path: str | os.PathLike) -> dict[str, Any]:
    """Read a FLAME-format model file and validate it.

    Parameters
    ----------
    path : str or os.PathLike
        FLAME 2020/2023 ``.pkl`` or our ``.npz``. Files with another suffix are
        recognised by content (a zip archive is read as ``.npz``, anything else as a pickle).

    Returns
    -------
    dict
        The required keys (see module docstring) as numpy arrays (``J_regressor``
        dense float64, ``kintree_table`` and ``f`` int64) plus every extra key
        (numpy arrays where possible).

    Raises
    ------
    FlameError
        Missing file, unreadable or corrupt file, missing keys, inconsistent sizes,
        non-finite values or face indices out of range; the message names the file
        and key, the expected and the found.
    """
    p = Path(path)
    if not p.exists():
        raise FlameError(f"{p}: file not found (expected a FLAME .pkl or a holo_viewer .npz model)")
    suffix = p.suffix.lower()
    if suffix == ".npz":
        data = _load_npz(p)
    elif suffix in (".pkl", ".pickle"):
        data = _load_pkl(p)
    else:
        try:
            is_zip = zipfile.is_zipfile(p)
        except OSError as exc:
            raise FlameError(f"{p}: cannot read ({exc})") from exc
        data = _load_npz(p) if is_zip else _load_pkl(p)
    return validate_flame_arrays(data, source=str(p))


# --------------------------------------------------------------------------- validation


def _dense(value: Any) -> np.ndarray:
    if hasattr(value, "toarray") and callable(value.toarray):  # scipy sparse matrix / array
        return np.asarray(value.toarray())
    if isinstance(value, ChumpyStub):
        return value.to_array("J_regressor", "<arrays>")
    return np.asarray(value)


def _check(value: Any, key: str, shape: tuple, sizes: dict[str, int], source: str,
           kind: str = "float") -> np.ndarray:
    """check_array for file data: FlameError naming the file and key."""
    arr = _dense(value)
    if kind == "float":
        if not (np.issubdtype(arr.dtype, np.floating) or np.issubdtype(arr.dtype, np.integer)):
            raise FlameError(f"{source}: {key}: expected a real-valued array of shape "
                             f"{_fmt(shape)}, found dtype {arr.dtype}")
        arr = arr.astype(np.float64)
    else:
        if np.issubdtype(arr.dtype, np.floating):
            if not np.all(np.isfinite(arr)) or np.any(arr != np.round(arr)):
                raise FlameError(f"{source}: {key}: expected integer indices, found non-integer values")
        elif not np.issubdtype(arr.dtype, np.integer):
            raise FlameError(f"{source}: {key}: expected an integer array, found dtype {arr.dtype}")
        arr = arr.astype(np.int64)
    # Only the named sizes this key uses go into the message.
    bound = {k: sizes[k] for k in shape if isinstance(k, str) and k in sizes}
    try:
        check_array(arr, key, shape, sizes=bound, finite=True)
    except InputError as exc:
        raise FlameError(f"{source}: {exc}") from exc
    sizes.update(bound)
    return arr


def _fmt(shape: tuple) -> str:
    return "(" + ", ".join(str(s) for s in shape) + ")"


def validate_flame_arrays(arrays: Mapping[str, Any], source: str = "<arrays>") -> dict[str, Any]:
    """Check keys, sizes and values of FLAME-format arrays and normalise their types.

    Parameters
    ----------
    arrays : mapping
        Key -> array (numpy, scipy sparse for ``J_regressor``, or a chumpy stub).
    source : str
        Name used in error messages (usually the file path).

    Returns
    -------
    dict
        Required keys as float64 / int64 numpy arrays (``J_regressor`` dense,
        ``kintree_table[0, 0]`` set to -1), extras passed through (``np.asarray``
        where possible).

    Raises
    ------
    FlameError
        Naming the key, the expected and the found.
    """
    if not isinstance(arrays, Mapping):
        raise FlameError(f"{source}: expected a mapping of FLAME arrays, found {type(arrays).__name__}")
    missing = [k for k in REQUIRED_KEYS if k not in arrays]
    if missing:
        raise FlameError(f"{source}: missing key{'s' if len(missing) > 1 else ''} "
                         f"{', '.join(repr(k) for k in missing)} (a FLAME model needs {', '.join(REQUIRED_KEYS)}; "
                         f"found keys {sorted(arrays)})")
    sizes: dict[str, int] = {}
    n_j, n_p = N_JOINTS, 9 * (N_JOINTS - 1)
    out: dict[str, Any] = {}
    out["v_template"] = _check(arrays["v_template"], "v_template", ("V", 3), sizes, source)
    out["shapedirs"] = _check(arrays["shapedirs"], "shapedirs", ("V", 3, "K"), sizes, source)
    out["posedirs"] = _check(arrays["posedirs"], "posedirs", ("V", 3, n_p), sizes, source)
    out["J_regressor"] = _check(arrays["J_regressor"], "J_regressor", (n_j, "V"), sizes, source)
    out["weights"] = _check(arrays["weights"], "weights", ("V", n_j), sizes, source)
    kin = _dense(arrays["kintree_table"])
    if np.issubdtype(kin.dtype, np.unsignedinteger):
        kin = kin.astype(np.int64)  # FLAME stores the root's parent as 2**32 - 1
        kin[kin > np.iinfo(np.int32).max] = -1
    out["kintree_table"] = _check(kin, "kintree_table", (2, n_j), sizes, source, kind="int")
    out["kintree_table"][0, 0] = -1
    parents = out["kintree_table"][0]
    for k in range(1, N_JOINTS):
        if not 0 <= parents[k] < k:
            raise FlameError(f"{source}: kintree_table: expected parent of joint {k} in [0, {k}), "
                             f"found {parents[k]} (parents {parents.tolist()})")
    f = _check(arrays["f"], "f", ("F", 3), sizes, source, kind="int")
    n_v = sizes["V"]
    if f.size and (f.min() < 0 or f.max() >= n_v):
        bad = int(f.max()) if f.max() >= n_v else int(f.min())
        raise FlameError(f"{source}: f: expected vertex indices in [0, {n_v}), found {bad}")
    out["f"] = f
    for key, value in arrays.items():
        if key in out:
            continue
        try:
            out[key] = _dense(value)
        except Exception:  # noqa: BLE001 - odd extras are passed through unchanged
            out[key] = value
    return out


# --------------------------------------------------------------------------- npz writer


def save_flame_npz(path: str | os.PathLike, arrays: Mapping[str, Any]) -> Path:
    """Validate FLAME-format arrays and write them as an ``.npz`` atomically.

    Parameters
    ----------
    path : str or os.PathLike
        Target file (conventionally ``*.npz``).
    arrays : mapping
        Required keys plus extras (numpy arrays, numbers or strings; no Python objects).

    Returns
    -------
    pathlib.Path
        The written path.

    Raises
    ------
    FlameError
        Invalid arrays, or an extra key that cannot be stored without pickling.
    """
    data = validate_flame_arrays(arrays, source=str(path))
    out: dict[str, np.ndarray] = {}
    for key, value in data.items():
        arr = np.asarray(value)
        if arr.dtype == object:
            raise FlameError(f"{path}: {key}: expected a numeric or string array, found Python objects "
                             f"({type(value).__name__}); an .npz model stores no pickled objects")
        out[key] = arr
    target = Path(path)
    with atomic_write(target) as fh:
        np.savez(fh, **out)
    return target
