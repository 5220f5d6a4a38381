"""The system graph: sub-models plus connections output → input (thesis 3.2 "data assignment").

A :class:`System` is built in code (or from a TOML file by :mod:`cosimstep.config`) and checked
as a whole: :meth:`System.problems` lists *every* problem at once. :meth:`System.compile` turns a
valid system into flat index tables the masters use in their hot loop.
"""

from __future__ import annotations

import dataclasses
import graphlib
import itertools
from collections.abc import Iterator
from dataclasses import dataclass, field

import numpy as np

from cosimstep.errors import ConfigurationError, Problem
from cosimstep.submodel import Port, SubModel
from cosimstep.units import UnitError, conversion


@dataclass(frozen=True)
class Connection:
    """``target = gain * convert_units(source) + offset``."""

    source: str
    target: str
    gain: float = 1.0
    offset: float = 0.0
    where: str = ""
    round: bool = False
    """Declared rounding: a real value may feed an integer or boolean input (rounded to the
    nearest integer there). Without it such a connection is refused."""

    @property
    def label(self) -> str:
        return self.where or f"connection {self.source} -> {self.target}"


def _kind_mismatch(out_kind: str, in_kind: str, c: Connection) -> str:
    """Why a value of ``out_kind`` cannot feed an input of ``in_kind`` unrounded ("" if it
    can): integers and booleans convert to reals and booleans to integers; the other way, or
    through a gain or offset, the values need not be whole numbers. Strings and byte strings
    (codes) go only to their own kind, unscaled and unrounded."""
    scaled = c.gain != 1.0 or c.offset != 0.0
    if out_kind in _CODED or in_kind in _CODED:
        if out_kind == in_kind and not scaled and not c.round:
            return ""
        how = " scaled or rounded by the connection" if out_kind == in_kind else ""
        return f"{_article(out_kind)} {out_kind} output{how} feeds {in_kind} input '{c.target}'"
    if in_kind == "real" or c.round:
        return ""
    if not scaled and (out_kind == in_kind or (out_kind, in_kind) == ("boolean", "integer")):
        return ""
    what = f"{out_kind} output" + (" scaled by the connection" if scaled else "")
    return f"{_article(out_kind)} {what} feeds {in_kind} input '{c.target}'"


_CODED = ("string", "binary")  # kinds whose floats are codes (cosimstep.symbols)


PortMaps = tuple[dict[str, Port], dict[str, Port]]
"""Every output, and every input, by its address ``model.port`` (two flat dicts: a system of
thousands of models would otherwise make a dict or two per model on every check)."""


def _names(address: str, port: Port | None) -> bool:
    """``address`` found ``port`` and, read as :func:`split_address` reads it, names its model
    and that port (a key alone could join a dotted model name)."""
    model, _, name = address.partition(".")
    return port is not None and bool(model) and name == port.name


def _article(word: str) -> str:
    return "an" if word[0] in "aeiou" else "a"


def _loop_ports(components: list[set[str]]) -> list[list[str]]:
    """The algebraic loops among strongly connected ``components``: those of several ports."""
    return [sorted(c) for c in components if len(c) > 1]


def _components(graph: dict[str, set[str]]) -> list[set[str]]:
    """Strongly connected components of a dependency graph (SciPy's csgraph)."""
    from scipy.sparse import csr_matrix
    from scipy.sparse.csgraph import connected_components

    nodes = sorted(set(graph) | {d for deps in graph.values() for d in deps})
    at = {n: i for i, n in enumerate(nodes)}
    edges = [(at[n], at[d]) for n, deps in graph.items() for d in deps]
    rows, cols = zip(*edges) if edges else ((), ())
    adjacency = csr_matrix((np.ones(len(edges)), (rows, cols)), shape=(len(nodes), len(nodes)))
    count, labels = connected_components(adjacency, directed=True, connection="strong")
    out: list[set[str]] = [set() for _ in range(count)]
    for node, label in zip(nodes, labels, strict=True):
        out[label].add(node)
    return out


def split_address(address: str) -> tuple[str, str]:
    """``"model.port"`` → ``("model", "port")``; the port part may itself contain dots."""
    model, sep, port = address.partition(".")
    if not sep or not model or not port:
        raise ValueError(f"'{address}' is not of the form model.port")
    return model, port


@dataclass
class CompiledSystem:
    """Flat index tables over all outputs of all models (the exchanged-value vector ``Y``).

    For model ``k``, input ``j`` takes ``a[k][j] * Y[src[k][j]] + b[k][j]``; an unconnected input
    has ``a = 0`` and ``b`` its start value.
    """

    names: list[str]
    models: list[SubModel]
    output_slices: list[slice]
    output_names: list[str]
    output_units: list[str]
    src: list[np.ndarray]
    a: list[np.ndarray]
    b: list[np.ndarray]
    feedthrough_order: list[int]
    loops: list[tuple[int, ...]] = field(default_factory=list)
    """Algebraic loops: the direct-feedthrough models of each, solved together at every
    communication point (:meth:`~cosimstep.masters.Master.settle`). ``feedthrough_order``
    lists every feedthrough model once, a loop's models together, in the order to settle."""
    owners: list[int] = field(default_factory=list)
    """The model (index) each output column belongs to."""

    @property
    def n_outputs(self) -> int:
        return len(self.output_names)


@dataclass
class System:
    """Sub-models and their connections."""

    models: dict[str, SubModel] = field(default_factory=dict)
    connections: list[Connection] = field(default_factory=list)
    origins: dict[str, str] = field(default_factory=dict)

    def add(self, name: str, model: SubModel, where: str = "") -> System:
        """Add a sub-model under an instance name (the ``model`` in ``model.port``)."""
        if "." in name or not name:
            raise ValueError(f"model name `{name}` must be non-empty and contain no '.'")
        if name in self.models:
            raise ValueError(f"a model named `{name}` is already in the system")
        self.models[name] = model
        self.origins[name] = where or f"model '{name}'"
        return self

    def connect(self, source: str, target: str, gain: float = 1.0, offset: float = 0.0,
                where: str = "", *, round: bool = False) -> System:
        """Connect output ``source`` ("model.port") to input ``target``; ``round`` lets a real
        value (or a scaled one) feed an integer or boolean input."""
        self.connections.append(Connection(source, target, gain, offset, where, round))
        return self

    # -- validation --------------------------------------------------------------------------
    def problems(self) -> list[Problem]:
        """Every problem in the system; an empty list means it can run."""
        ports = self._port_maps()
        return self._problems(*self._expand(ports), ports)

    def _problems(self, links: list[Connection], mismatched: list[tuple[Connection, int, int]],
                  ports: PortMaps) -> list[Problem]:
        """:meth:`problems`, given what :meth:`_expand` found (compiling a large system needs
        its links again, and finding them is its costliest part)."""
        problems = self._duplicate_ports(ports)
        problems += [Problem(c.label, f"arrays of different sizes: {outs} outputs, {ins} inputs",
                             "connect arrays of equal size, or single elements (model.y[2])")
                     for c, outs, ins in mismatched]
        fed: dict[tuple[str, str], Connection] = {}
        for c in links:
            problems.extend(self._check_connection(c, fed, ports))
        for name, model in self.models.items():
            for port in model.inputs:
                if (name, port.name) not in fed and port.start is None:
                    problems.append(Problem(
                        self.origins[name],
                        f"input '{name}.{port.name}' is not connected and has no start value",
                        "connect an output to it or give it a start value"))
        if self.models and not any(model.outputs for model in self.models.values()):
            # nothing to exchange or record (and nothing an unconnected input could be read
            # through: it ended in an IndexError)
            problems.append(Problem(
                self.origins[next(iter(self.models))],
                "no sub-model has an output: a run would exchange and record nothing",
                "give a sub-model an output (a sink can output what it accumulates)"))
        return problems

    def _duplicate_ports(self, maps: PortMaps) -> list[Problem]:
        """A port name declared twice by one model: a connection could not say which it means.
        (Counted against the maps first, which hold each address once.)"""
        declared = [len(m.outputs) for m in self.models.values()], \
            [len(m.inputs) for m in self.models.values()]
        if len(maps[0]) == sum(declared[0]) and len(maps[1]) == sum(declared[1]):
            return []
        problems = []
        for name, model in self.models.items():
            for kind, ports in (("output", model.outputs), ("input", model.inputs)):
                names = [p.name for p in ports]
                for twice in sorted({n for n in names if names.count(n) > 1}):
                    problems.append(Problem(self.origins[name], f"model '{name}' declares "
                                            f"{kind} '{twice}' more than once",
                                            f"give every {kind} of a model its own name"))
        return problems

    def _check_connection(self, c: Connection, fed: dict[tuple[str, str], Connection],
                          maps: PortMaps) -> list[Problem]:
        """What is wrong with connection ``c`` (``fed``: the inputs connected so far, to which
        it is added). Both ends are looked up by address first, which a system of thousands of
        connections needs; an end not found so is explained by :meth:`_address_problems`."""
        out_port, in_port = maps[0].get(c.source), maps[1].get(c.target)
        if out_port is None or in_port is None or not (_names(c.source, out_port)
                                                       and _names(c.target, in_port)):
            return list(self._address_problems(c, maps))
        problems = []
        key = (c.target.partition(".")[0], in_port.name)
        if key in fed:
            problems.append(Problem(c.label, f"input '{c.target}' already has a source "
                                    f"({fed[key].source})", "an input takes exactly one "
                                    "connection"))
        else:
            fed[key] = c
        out_kind, in_kind = out_port.kind, in_port.kind
        coded = out_kind in _CODED or in_kind in _CODED
        try:
            if not coded:  # text and bytes have no unit; their kinds are checked below
                conversion(out_port.unit, in_port.unit)
        except UnitError as exc:
            problems.append(Problem(c.label, f"unit mismatch: {exc}", "connect ports of "
                                    "compatible units or fix the unit declarations"))
        if in_kind == "real" and not coded:  # any number feeds a real input
            return problems
        mismatch = _kind_mismatch(out_kind, in_kind, c)
        if mismatch and coded:
            problems.append(Problem(c.label, mismatch, f"connect a {in_port.kind} output, "
                                    "without gain, offset or rounding"))
        elif mismatch:
            problems.append(Problem(c.label, mismatch, "connect an output of the same kind, or "
                                    "declare the rounding on the connection (round = true)"))
        return problems

    def _address_problems(self, c: Connection, maps: PortMaps) -> Iterator[Problem]:
        """Why an end of ``c`` names no port: a malformed address, an unknown model, or a
        port the model does not have."""
        for role, address, kind in (("from", c.source, "output"), ("to", c.target, "input")):
            try:
                model_name, port_name = split_address(address)
            except ValueError as exc:
                yield Problem(c.label, f"`{role}` {exc}", "write it as model.port")
                continue
            model = self.models.get(model_name)
            if model is None:
                known = ", ".join(sorted(self.models)) or "none"
                yield Problem(c.label, f"`{role}` names unknown model '{model_name}'",
                              f"use one of: {known}")
                continue
            if not _names(address, maps[kind == "input"].get(address)):
                ports = model.outputs if kind == "output" else model.inputs
                known = ", ".join(p.name for p in ports) or "none"
                yield Problem(c.label, f"`{role}`: model '{model_name}' has no {kind} "
                              f"'{port_name}'", f"its {kind}s are: {known}")

    def _links(self) -> list[Connection]:
        """The connections port to port: one between two arrays (``a.y -> b.u``, ports
        ``y[1]`` … and ``u[1]`` … of equal count) stands for one per element pair."""
        return self._expand(self._port_maps())[0]

    def _port_maps(self) -> PortMaps:
        """Every output and every input by its address."""
        return ({f"{n}.{p.name}": p for n, m in self.models.items() for p in m.outputs},
                {f"{n}.{p.name}": p for n, m in self.models.items() for p in m.inputs})

    def _expand(self, names: PortMaps
                ) -> tuple[list[Connection], list[tuple[Connection, int, int]]]:
        """:meth:`_links`, and the array connections of unequal sizes (with both sizes), each
        connection looked at once."""
        links, mismatched = [], []
        for c in self.connections:
            out = self._array_ports(c.source, True, names)
            ins = self._array_ports(c.target, False, names) if out is not None else None
            if out is None or ins is None:
                links.append(c)
            elif len(out) == len(ins):
                links.extend(dataclasses.replace(c, source=x, target=y)
                             for x, y in zip(out, ins))
            else:
                mismatched.append((c, len(out), len(ins)))
        return links, mismatched

    def _array_ports(self, address: str, outputs: bool, names: PortMaps) -> list[str] | None:
        """``model.y[1]``, ``model.y[2]`` … when ``address`` names an array of ``model``
        (no port of that name, but elements), else ``None``; ``names``: every port by its
        address."""
        model_name, sep, port = address.partition(".")
        if not (sep and model_name and port) or address in names[not outputs] \
                or model_name not in self.models:
            return None  # (a malformed address or an unknown model: reported as such)
        model = self.models[model_name]
        ports = model.outputs if outputs else model.inputs
        elements = [f"{model_name}.{p.name}" for p in ports if p.name.startswith(port + "[")]
        return elements or None

    def _port_graph(self, links: list[Connection] | None = None) -> dict[str, set[str]]:
        """Dependencies at one instant: an input depends on its source; a feedthrough output on
        its inputs. A cycle in this graph is an algebraic loop."""
        graph: dict[str, set[str]] = {}
        for c in self._links() if links is None else links:
            graph.setdefault(f"{c.target}", set()).add(f"{c.source}")
        for name, model in self.models.items():
            for out, ins in model.capabilities.feedthrough.items():
                graph.setdefault(f"{name}.{out}", set()).update(f"{name}.{i}" for i in ins)
        return graph

    def loops(self) -> list[list[str]]:
        """The algebraic loops: each a cycle of ports through direct feedthrough (the ports
        of one strongly connected component of :meth:`_port_graph`, sorted)."""
        return _loop_ports(_components(self._port_graph()))

    def _settle_blocks(self, names: list[str], graph: dict[str, set[str]],
                       components: list[set[str]]) -> list[tuple[int, ...]]:
        """The feedthrough models to settle, in dependency order: one model alone, or the
        models of an algebraic loop together (strongly connected components of the port
        ``graph``, condensed and sorted topologically)."""
        index = {name: k for k, name in enumerate(names)}
        of = {node: i for i, c in enumerate(components) for node in c}
        condensed: dict[int, set[int]] = {i: set() for i in range(len(components))}
        for node, deps in graph.items():
            condensed[of[node]].update(of[d] for d in deps if of[d] != of[node])
        blocks: list[tuple[int, ...]] = []
        for i in graphlib.TopologicalSorter(condensed).static_order():
            models = sorted({index[m] for m, _, port in
                             (n.partition(".") for n in components[i])
                             if m in self.models
                             and self.models[m].capabilities.feedthrough.get(port)})
            if models and not any(k in b for b in blocks for k in models):
                blocks.append(tuple(models))
        return blocks

    def validate(self) -> None:
        """Raise :class:`ConfigurationError` listing every problem, if there is any."""
        problems = self.problems()
        if problems:
            raise ConfigurationError(problems)

    # -- compilation -------------------------------------------------------------------------
    def compile(self) -> CompiledSystem:
        """Validate and build the index tables for a master."""
        ports = self._port_maps()
        links, mismatched = self._expand(ports)
        problems = self._problems(links, mismatched, ports)
        if problems:
            raise ConfigurationError(problems)
        names = list(self.models)
        models = [self.models[n] for n in names]
        # the port maps hold every address once, models and ports in declaration order (a
        # port declared twice was refused above), so the columns are their order
        out_names = list(ports[0])
        out_units = [port.unit for port in ports[0].values()]
        global_index = {address: j for j, address in enumerate(out_names)}
        slices, owners, offset = [], [], 0
        for k, model in enumerate(models):
            count = len(model.outputs)
            slices.append(slice(offset, offset + count))
            owners.extend([k] * count)
            offset += count
        if len(out_names) != offset:  # two addresses alike: a model name with a '.' put
            raise ConfigurationError([Problem(  # into `models` past `add`
                "models", "two outputs have one address model.port",
                "add models with System.add (a name without '.')")])
        by_target = {c.target: c for c in links}
        # every model's input table as a view into one array for all (a system of thousands of
        # models would otherwise spend most of its compile allocating arrays of one element)
        s_all, a_all, b_all, bounds = [], [], [], [0]
        for address, port in ports[1].items():
            c = by_target.get(address)
            if c is None:  # validated: unconnected inputs have a start value
                s_all.append(0)
                a_all.append(0.0)
                b_all.append(float(port.start))
                continue
            scale, shift = conversion(ports[0][c.source].unit, port.unit)
            s_all.append(global_index[c.source])
            a_all.append(c.gain * scale)
            b_all.append(c.gain * shift + c.offset)
        for model in models:
            bounds.append(bounds[-1] + len(model.inputs))
        tables = (np.array(s_all, dtype=int), np.array(a_all, dtype=float),
                  np.array(b_all, dtype=float))
        src, a, b = ([t[i:j] for i, j in itertools.pairwise(bounds)] for t in tables)
        blocks, loops = self._feedthrough_blocks(names, links)
        order = [k for block in blocks for k in block]
        return CompiledSystem(names, models, slices, out_names, out_units, src, a, b, order,
                              loops, owners)

    def _feedthrough_blocks(self, names: list[str], links: list[Connection]
                            ) -> tuple[list[tuple[int, ...]], list[tuple[int, ...]]]:
        """The feedthrough models in the order to settle them (:meth:`_settle_blocks`) and the
        blocks among them that are algebraic loops. Without feedthrough there is neither, and
        no graph to build: every edge then runs from an input to an output, so no cycle."""
        if not any(m.capabilities.feedthrough for m in self.models.values()):
            return [], []
        graph = self._port_graph(links)
        components = _components(graph)
        blocks = self._settle_blocks(names, graph, components)
        loop_ports = _loop_ports(components)
        loops = [b for b in blocks if len(b) > 1 or any(
            p.partition(".")[0] == names[b[0]] for c in loop_ports for p in c)]
        return blocks, loops
