"""Objects of the simulation as plain JSON and numpy arrays, and back: the checkpoint's codec.

    tree, arrays = encode(value)          # tree: JSON-ready; arrays: {"a0": ndarray, ...}
    value = decode(tree, arrays)

Only data is stored: None, bools, ints, floats (non-finite ones tagged), strings, paths, lists,
tuples, sets, dicts (keys of any of these kinds, in order), numpy arrays and scalars (in
``arrays``), scipy sparse CSR/CSC matrices (their three arrays), k-d trees (their points; rebuilt
on load) and instances of the project's own classes named in :data:`CLASSES` (dataclasses by
their ``__init__`` fields, named tuples by their items). Decoding builds only those: a class name
outside the list is refused, so loading a checkpoint never imports or runs anything else.
A model's memos (:data:`MEMOS`) keep only their slots whose content depends on the run's history
and start with the others empty: a memo computed again from the model gives the same answer, but
the contact response (``fem.contact_response.ResponseCache``) is learnt node by node as contacts
come, and CHOLMOD's back-substitution of a batch of columns differs in the last bits from that of
the same columns in other batches, so a run resumed with it rebuilt would drift from the run that
was not stopped.
An array or object reached twice is stored once and decoded as one object again, so what the
model shares stays shared.
"""
import dataclasses
import importlib
import math
from pathlib import Path, PurePath

import numpy as np
import scipy.sparse as sp
from scipy.spatial import cKDTree

# the classes a checkpoint may hold: the hybrid model and state, the FEM and rigid models and
# states they are made of, their step and event history, the events and the scene records
CLASSES = (
    "hybrid.coupling.model:HybridModel", "hybrid.coupling.model:HybridState",
    "fem.model:FemModel", "fem.model:FemState", "fem.assembly:ElementData",
    "fem.fracture:FractureModel", "fem.split:TetFaces",
    "rigid.model:RigidModel", "rigid.model:RigidState", "rigid.resolve:ContactSettings",
    "hybrid.coupling.memory:ContactMemory", "hybrid.coupling.resting:Resting",
    "hybrid.coupling.fracture:FractureBody", "hybrid.coupling.fracture:FractureEvent",
    "hybrid.coupling.switch:Parked", "hybrid.coupling.touches:Touches", "hybrid.coupling.auto:Switch",
    "hybrid.coupling.events:ReferenceUpdate",
    "hybrid.app.scene.records:Scene", "hybrid.app.scene.records:Simulation",
    "hybrid.app.scene.records:Solver", "hybrid.app.scene.records:Plane",
    "hybrid.app.scene.records:Shape", "hybrid.app.scene.records:Damping",
    "hybrid.app.scene.records:Auto", "hybrid.app.scene.records:Anchor",
    "hybrid.app.scene.records:Load", "hybrid.app.scene.records:Unbreakable",
    "hybrid.app.scene.records:Body",
)
# memos and the slots of each a checkpoint keeps (the others start empty when loaded): a model's
# contact response and the held variant of it that has its own
MEMOS = (("fem.cache:FemCache", ("response", "held")), ("hybrid.coupling.model:CouplingCache", ()))
# plain classes stored by their attributes, which must be exactly these
OBJECTS = (("fem.contact_response:ResponseCache",
            ("dt", "known", "slot", "_W", "columns", "block", "block_columns")),)
SPARSE = {"csr_matrix": sp.csr_matrix, "csc_matrix": sp.csc_matrix,
          "csr_array": sp.csr_array, "csc_array": sp.csc_array}


class CodecError(ValueError):
    """A value the codec cannot store, or a stored tree it will not build (the message says what)."""


def class_name(cls):
    """``module:qualname`` of a class, the name :data:`CLASSES` lists."""
    return f"{cls.__module__}:{cls.__qualname__}"


def allowed_class(name):
    """The class called ``name`` (``module:qualname``) if :data:`CLASSES`, :data:`MEMOS` or
    :data:`OBJECTS` lists it; CodecError otherwise (nothing is imported for another name)."""
    if name not in CLASSES and name not in dict(MEMOS) and name not in dict(OBJECTS):
        raise CodecError(f"class {name!r} is not one a checkpoint may hold")
    module, _, qualname = name.partition(":")
    return getattr(importlib.import_module(module), qualname)


class _Encoder:
    """One encoding pass: the arrays found so far and the objects already stored (by id)."""

    def __init__(self):
        self.arrays, self.seen, self.keep = {}, {}, []

    def array(self, value):
        """The name under which ``value`` (an ndarray or numpy scalar) is stored."""
        name = f"a{len(self.arrays)}"
        self.arrays[name] = value
        return name

    def shared(self, value, build):
        """``{"ref": k}`` for an object stored before, else its tree from ``build()``, numbered."""
        key = id(value)
        if key in self.seen:
            return {"ref": self.seen[key]}
        self.seen[key] = len(self.seen)
        self.keep.append(value)             # ids stay unique while the pass runs
        return {"id": self.seen[key], **build()}

    def encode(self, value):
        """The JSON-ready tree of ``value``."""
        if value is None or isinstance(value, (bool, str)):
            return value
        if isinstance(value, int) and not isinstance(value, np.integer):
            return value
        if isinstance(value, float) and not isinstance(value, np.floating):
            return value if math.isfinite(value) else {"float": repr(value)}
        if isinstance(value, np.generic):
            return {"scalar": self.array(np.asarray(value))}
        if isinstance(value, np.ndarray):
            if value.dtype.hasobject:
                raise CodecError("an array of Python objects cannot be stored")
            return self.shared(value, lambda: {"array": self.array(value)})
        if isinstance(value, PurePath):
            return {"path": str(value)}
        if sp.issparse(value):
            return self.shared(value, lambda: self._sparse(value))
        if isinstance(value, cKDTree):
            return self.shared(value, lambda: {"kdtree": self.encode(value.data),
                                               "leafsize": int(value.leafsize)})
        return self._container(value)

    def _sparse(self, value):
        kind = type(value).__name__
        if kind not in SPARSE:
            raise CodecError(f"a sparse matrix of kind {kind} cannot be stored")
        return {"sparse": kind, "shape": list(value.shape), "data": self.array(value.data),
                "indices": self.array(value.indices), "indptr": self.array(value.indptr)}

    def _container(self, value):
        if isinstance(value, tuple) and hasattr(value, "_fields"):
            name = class_name(type(value))
            allowed_class(name)
            return self.shared(value, lambda: {"namedtuple": name, "fields": list(value._fields),
                                               "items": [self.encode(v) for v in value]})
        if dataclasses.is_dataclass(value) and not isinstance(value, type):
            return self.shared(value, lambda: self._dataclass(value))
        if isinstance(value, (list, tuple, set, frozenset)):
            kind = type(value).__name__
            if kind not in ("list", "tuple", "set", "frozenset"):
                raise CodecError(f"a {kind} cannot be stored")
            return {kind: [self.encode(v) for v in value]}
        if isinstance(value, dict) and type(value) is dict:
            return {"dict": [[self.encode(k), self.encode(v)] for k, v in value.items()]}
        name = class_name(type(value))
        if name in dict(OBJECTS):
            return self.shared(value, lambda: self._object(name, value))
        raise CodecError(f"a value of type {name} cannot be stored")

    def _object(self, name, value):
        attributes = dict(OBJECTS)[name]
        if tuple(sorted(vars(value))) != tuple(sorted(attributes)):
            raise CodecError(f"{name} has attributes {sorted(vars(value))}, the checkpoint format "
                             f"stores {sorted(attributes)}")
        return {"object": name, "attributes": {a: self.encode(getattr(value, a)) for a in attributes}}

    def _dataclass(self, value):
        name = class_name(type(value))
        allowed_class(name)
        kept = dict(MEMOS).get(name)
        fields, rebuilt = {}, []
        for f in dataclasses.fields(value):
            if not f.init:
                continue                    # derived in __post_init__, or a memo of its own
            if kept is not None and f.name not in kept:
                rebuilt.append(f.name)      # a memo's slot that is computed again
            else:
                fields[f.name] = self.encode(getattr(value, f.name))
        return {"dataclass": name, "fields": fields, "rebuilt": rebuilt}


def encode(value):
    """``(tree, arrays)``: the JSON-ready tree of ``value`` and the numpy arrays it names
    (``{"a0": ndarray, ...}``). CodecError for a value the format cannot hold."""
    encoder = _Encoder()
    tree = encoder.encode(value)
    return tree, encoder.arrays


class _Decoder:
    """One decoding pass: the arrays and the objects built so far (by their stored number)."""

    def __init__(self, arrays):
        self.arrays, self.built = arrays, {}

    def array(self, name):
        """The stored array ``name``; CodecError when the file has none by that name."""
        if not isinstance(name, str) or name not in self.arrays:
            raise CodecError(f"the checkpoint names an array {name!r} it does not hold")
        return self.arrays[name]

    def decode(self, tree):
        """The value of ``tree``."""
        if tree is None or isinstance(tree, (bool, int, float, str)):
            return tree
        if isinstance(tree, list) or not isinstance(tree, dict) or not tree:
            raise CodecError(f"a stored value is malformed: {str(tree)[:80]}")
        if "ref" in tree:
            if tree["ref"] not in self.built:
                raise CodecError(f"a stored value refers to object {tree['ref']} before it is built")
            return self.built[tree["ref"]]
        value = self._value(tree)
        if "id" in tree:
            self.built[tree["id"]] = value
        return value

    def _value(self, tree):
        kind = next(k for k in tree if k != "id")
        if kind == "float":
            return float(tree["float"])
        if kind == "scalar":
            return self.array(tree["scalar"])[()]
        if kind == "array":
            return self.array(tree["array"])
        if kind == "path":
            return Path(tree["path"])
        if kind == "sparse":
            return self._sparse(tree)
        if kind == "kdtree":
            return cKDTree(self.decode(tree["kdtree"]), leafsize=int(tree["leafsize"]))
        if kind in ("list", "tuple", "set", "frozenset"):
            items = [self.decode(v) for v in tree[kind]]
            return {"list": list, "tuple": tuple, "set": set, "frozenset": frozenset}[kind](items)
        if kind == "dict":
            return {self.decode(k): self.decode(v) for k, v in tree["dict"]}
        if kind == "namedtuple":
            return self._namedtuple(tree)
        if kind == "dataclass":
            return self._dataclass(tree)
        if kind == "object":
            return self._object(tree)
        raise CodecError(f"a stored value has an unknown kind {kind!r}")

    def _sparse(self, tree):
        if tree["sparse"] not in SPARSE:
            raise CodecError(f"a stored sparse matrix has an unknown kind {tree['sparse']!r}")
        parts = (self.array(tree["data"]), self.array(tree["indices"]), self.array(tree["indptr"]))
        return SPARSE[tree["sparse"]](parts, shape=tuple(tree["shape"]))

    def _namedtuple(self, tree):
        cls = allowed_class(tree["namedtuple"])
        if list(cls._fields) != list(tree["fields"]):
            raise CodecError(f"{tree['namedtuple']}: stored with fields {tree['fields']}, this "
                             f"version has {list(cls._fields)}")
        return cls(*(self.decode(v) for v in tree["items"]))

    def _dataclass(self, tree):
        name = tree["dataclass"]
        cls = allowed_class(name)
        expected = {f.name for f in dataclasses.fields(cls) if f.init}
        stored = set(tree["fields"]) | set(tree["rebuilt"])
        if stored != expected or (set(tree["rebuilt"]) and name not in dict(MEMOS)):
            raise CodecError(f"{name}: stored with fields {sorted(stored)}, this version has "
                             f"{sorted(expected)}")
        return cls(**{k: self.decode(v) for k, v in tree["fields"].items()})

    def _object(self, tree):
        name = tree["object"]
        if name not in dict(OBJECTS) or sorted(tree["attributes"]) != sorted(dict(OBJECTS)[name]):
            raise CodecError(f"{name}: not an object a checkpoint stores with these attributes")
        value = allowed_class(name).__new__(allowed_class(name))
        for attribute, item in tree["attributes"].items():
            setattr(value, attribute, self.decode(item))
        return value


def decode(tree, arrays):
    """The value stored as ``tree`` with its ``arrays`` (what :func:`encode` gave). CodecError
    for a malformed tree, a class outside :data:`CLASSES` or one whose fields have changed."""
    try:
        return _Decoder(arrays).decode(tree)
    except (KeyError, TypeError, StopIteration, AttributeError) as error:
        raise CodecError(f"a stored value is malformed ({type(error).__name__}: {error})") from None
