"""The Mamdani rule base as data: variables, membership functions and parsed rules.

``configs/fuzzy_rules.yaml`` holds the membership functions and the rules as readable
text (``if flatness is high and steepness is not low then score is high``). The text is
parsed once into a small AST whose leaves index a stacked membership array, so the
evaluators never touch strings. Errors name the rules file, the rule number and the word.
"""

from __future__ import annotations

import difflib
import hashlib
import itertools
import re
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

from slzcli.config import CONFIG_DIR, YamlLimitError, read_yaml_text, safe_yaml_load
from slzcli.errors import ConfigError

MF_KINDS = {"triangle": 3, "trapezoid": 4}
KEYWORDS = ("if", "then", "is", "not", "and", "or", "(", ")")


# ----------------------------------------------------------------------------- membership functions
@dataclass(frozen=True)
class MembershipFn:
    """A trapezoid ``(a, b, c, d)``: 0 outside [a, d], rising on [a, b], 1 on [b, c], falling on [c, d].

    A triangle is a trapezoid with b == c; a == b or c == d makes a shoulder (1 at the edge),
    as scikit-fuzzy's trimf/trapmf do.
    """

    a: float
    b: float
    c: float
    d: float

    @property
    def points(self) -> tuple[float, float, float, float]:
        return self.a, self.b, self.c, self.d

    def __call__(self, x: np.ndarray) -> np.ndarray:
        x = np.asarray(x)
        if self.b > self.a:
            up = np.clip((x - self.a) / (self.b - self.a), 0.0, 1.0)
        else:
            up = (x >= self.a).astype(x.dtype if x.dtype.kind == "f" else np.float64)
        if self.d > self.c:
            down = np.clip((self.d - x) / (self.d - self.c), 0.0, 1.0)
        else:
            down = (x <= self.d).astype(up.dtype)
        return np.minimum(up, down)

    def segments(self) -> list[tuple[float, float, float, float]]:
        """The sloped pieces as (y0, mu0, y1, mu1) lines; used for the exact centroid."""
        out = []
        if self.b > self.a:
            out.append((self.a, 0.0, self.b, 1.0))
        if self.d > self.c:
            out.append((self.c, 1.0, self.d, 0.0))
        return out


@dataclass(frozen=True)
class Variable:
    name: str
    universe: tuple[float, float]
    term_names: tuple[str, ...]
    terms: tuple[MembershipFn, ...]


# ----------------------------------------------------------------------------- rule AST
@dataclass(frozen=True)
class Is:
    """Leaf: membership of input ``var`` in ``term``; ``index`` into the stacked membership rows."""

    index: int


@dataclass(frozen=True)
class Not:
    arg: Node


@dataclass(frozen=True)
class And:
    args: tuple[Node, ...]


@dataclass(frozen=True)
class Or:
    args: tuple[Node, ...]


Node = Is | Not | And | Or


@dataclass(frozen=True)
class Rule:
    number: int
    text: str
    premise: Node
    term: int  # index of the output term


@dataclass(frozen=True)
class RuleBase:
    """Inputs, the output and the rules; ``leaves`` maps membership row -> (input, term)."""

    inputs: tuple[Variable, ...]
    output: Variable
    rules: tuple[Rule, ...]
    leaves: tuple[tuple[int, int], ...]
    source: str
    digest: str

    @property
    def input_names(self) -> tuple[str, ...]:
        return tuple(v.name for v in self.inputs)


# ----------------------------------------------------------------------------- loading
def resolve_rules_path(name: str) -> Path:
    """``scoring.fuzzy.rules``: a file in configs/ by bare name, else a path."""
    path = Path(name).expanduser()
    if not path.is_absolute() and (CONFIG_DIR / path).is_file():
        return CONFIG_DIR / path
    return path


def load_rules(name: str) -> RuleBase:
    """Read and parse the rules file named by ``scoring.fuzzy.rules``."""
    path = resolve_rules_path(name)
    key = "scoring.fuzzy.rules"
    if not path.is_file():
        raise ConfigError(key, f"rules file not found: {path}")
    text = read_yaml_text(path)
    try:
        data = safe_yaml_load(text)
    except yaml.YAMLError as err:
        mark = getattr(err, "problem_mark", None)
        where = f"line {mark.line + 1}" if mark else str(err).splitlines()[0]
        what = f"YAML refused: {err.reason}" if isinstance(err, YamlLimitError) else "not valid YAML"
        raise ConfigError("", f"{what} ({where})", source=str(path)) from err
    return parse_rule_base(data, source=str(path), digest=hashlib.sha256(text.encode()).hexdigest()[:16])


def parse_rule_base(data: object, source: str = "<rules>", digest: str = "") -> RuleBase:
    """Validate the YAML mapping and parse every rule."""
    if not isinstance(data, dict):
        raise ConfigError("", "the rules file must be a mapping with inputs, output, rules", source)
    for key in data:
        if key not in ("inputs", "output", "rules"):
            raise ConfigError(str(key), f"unknown key{did_you_mean(str(key), ('inputs', 'output', 'rules'))}", source)
    for key in ("inputs", "output", "rules"):
        if key not in data:
            raise ConfigError(key, "missing key", source)
    if not isinstance(data["inputs"], dict) or not data["inputs"]:
        raise ConfigError("inputs", "expected a mapping of input variables", source)
    if not isinstance(data["output"], dict) or len(data["output"]) != 1:
        raise ConfigError("output", "expected a mapping with exactly one output variable", source)
    inputs = tuple(_variable(name, spec, f"inputs.{name}", source) for name, spec in data["inputs"].items())
    (out_name, out_spec), = data["output"].items()
    output = _variable(out_name, out_spec, f"output.{out_name}", source)
    leaves = tuple((i, t) for i, var in enumerate(inputs) for t in range(len(var.terms)))
    rules_data = data["rules"]
    if not isinstance(rules_data, list) or not rules_data:
        raise ConfigError("rules", "expected a non-empty list of rule strings", source)
    rules = tuple(_parse_rule(text, n, inputs, output, leaves, source) for n, text in enumerate(rules_data, 1))
    if not digest:
        digest = hashlib.sha256(repr(data).encode()).hexdigest()[:16]
    return RuleBase(inputs, output, rules, leaves, source, digest)


def _variable(name: str, spec: object, key: str, source: str) -> Variable:
    if not isinstance(spec, dict) or set(spec) != {"universe", "terms"}:
        raise ConfigError(key, "expected a mapping with universe: [lo, hi] and terms:", source)
    uni = spec["universe"]
    if (not isinstance(uni, list) or len(uni) != 2 or not all(_is_number(v) for v in uni)
            or not float(uni[0]) < float(uni[1])):
        raise ConfigError(f"{key}.universe", f"expected [lo, hi] with lo < hi, got {uni!r}", source)
    terms = spec["terms"]
    if not isinstance(terms, dict) or not terms:
        raise ConfigError(f"{key}.terms", "expected a mapping of term: {triangle: [a, b, c]}", source)
    names, fns = [], []
    for tname, tspec in terms.items():
        tkey = f"{key}.terms.{tname}"
        if str(tname) in KEYWORDS:
            raise ConfigError(tkey, f"{tname!r} is a keyword of the rule language", source)
        if not isinstance(tspec, dict) or len(tspec) != 1:
            raise ConfigError(tkey, "expected {triangle: [a, b, c]} or {trapezoid: [a, b, c, d]}", source)
        (kind, pts), = tspec.items()
        if kind not in MF_KINDS:
            raise ConfigError(tkey, f"unknown shape {kind!r}{did_you_mean(str(kind), MF_KINDS)}", source)
        if (not isinstance(pts, list) or len(pts) != MF_KINDS[kind] or not all(_is_number(p) for p in pts)
                or any(float(p) > float(q) for p, q in itertools.pairwise(pts))):
            raise ConfigError(tkey, f"{kind} needs {MF_KINDS[kind]} non-decreasing numbers, got {pts!r}", source)
        p = [float(v) for v in pts]
        if p[0] == p[-1]:
            raise ConfigError(tkey, f"{kind} {pts!r} has zero width", source)
        fns.append(MembershipFn(p[0], p[1], p[1], p[2]) if kind == "triangle" else MembershipFn(*p))
        names.append(str(tname))
    return Variable(str(name), (float(uni[0]), float(uni[1])), tuple(names), tuple(fns))


def _is_number(v: object) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


# ----------------------------------------------------------------------------- rule parser
_TOKEN = re.compile(r"\s*(?:(\()|(\))|([A-Za-z_][A-Za-z0-9_]*)|(\S))")


class _Parser:
    """Recursive descent: premise := and ('or' and)*; and := unary ('and' unary)*;
    unary := 'not' unary | '(' premise ')' | VAR 'is' ['not'] TERM."""

    def __init__(self, text: str, number: int, inputs: tuple[Variable, ...], output: Variable,
                 leaves: tuple[tuple[int, int], ...], source: str) -> None:
        self.number, self.inputs, self.output, self.source = number, inputs, output, source
        self.leaf_index = {leaf: k for k, leaf in enumerate(leaves)}
        self.tokens: list[str] = []
        for m in _TOKEN.finditer(text.strip()):
            if m.group(4) is not None:
                self.fail(f"unexpected character {m.group(4)!r}")
            self.tokens.append(m.group(1) or m.group(2) or m.group(3))
        self.pos = 0

    def fail(self, reason: str) -> None:
        raise ConfigError(f"rule {self.number}", reason, self.source)

    def peek(self) -> str | None:
        return self.tokens[self.pos] if self.pos < len(self.tokens) else None

    def take(self, what: str) -> str:
        tok = self.peek()
        if tok is None:
            self.fail(f"rule ends early; expected {what}")
        self.pos += 1
        return tok  # type: ignore[return-value]

    def expect(self, word: str) -> None:
        tok = self.take(repr(word))
        if tok != word:
            self.fail(f"expected {word!r}, got {tok!r}{did_you_mean(tok, (word,))}")

    def rule(self) -> tuple[Node, int]:
        self.expect("if")
        premise = self.premise()
        self.expect("then")
        var = self.take("the output variable")
        if var != self.output.name:
            self.fail(f"unknown output variable {var!r}{did_you_mean(var, (self.output.name,))}")
        self.expect("is")
        term = self.take("an output term")
        if term not in self.output.term_names:
            self.fail(f"unknown term {term!r} of {var}{did_you_mean(term, self.output.term_names)}")
        if self.peek() is not None:
            self.fail(f"unexpected {self.peek()!r} after the consequent")
        return premise, self.output.term_names.index(term)

    def premise(self) -> Node:
        args = [self.conjunction()]
        while self.peek() == "or":
            self.pos += 1
            args.append(self.conjunction())
        return args[0] if len(args) == 1 else Or(tuple(_flatten(args, Or)))

    def conjunction(self) -> Node:
        args = [self.unary()]
        while self.peek() == "and":
            self.pos += 1
            args.append(self.unary())
        return args[0] if len(args) == 1 else And(tuple(_flatten(args, And)))

    def unary(self) -> Node:
        tok = self.peek()
        if tok == "not":
            self.pos += 1
            return Not(self.unary())
        if tok == "(":
            self.pos += 1
            node = self.premise()
            self.expect(")")
            return node
        var = self.take("an input variable")
        names = [v.name for v in self.inputs]
        if var not in names:
            self.fail(f"unknown input variable {var!r}{did_you_mean(var, names)}")
        self.expect("is")
        negate = self.peek() == "not"
        if negate:
            self.pos += 1
        term = self.take(f"a term of {var}")
        v = names.index(var)
        if term not in self.inputs[v].term_names:
            self.fail(f"unknown term {term!r} of {var}{did_you_mean(term, self.inputs[v].term_names)}")
        leaf: Node = Is(self.leaf_index[(v, self.inputs[v].term_names.index(term))])
        return Not(leaf) if negate else leaf


def _flatten(args: Iterable[Node], kind: type[And] | type[Or]) -> list[Node]:
    out: list[Node] = []
    for a in args:
        out.extend(a.args if isinstance(a, kind) else [a])
    return out


def _parse_rule(text: object, number: int, inputs: tuple[Variable, ...], output: Variable,
                leaves: tuple[tuple[int, int], ...], source: str) -> Rule:
    if not isinstance(text, str):
        raise ConfigError(f"rule {number}", f"expected a rule string, got {text!r}", source)
    premise, term = _Parser(text, number, inputs, output, leaves, source).rule()
    return Rule(number, " ".join(text.split()), premise, term)


def did_you_mean(word: str, candidates: Iterable[object]) -> str:
    close = difflib.get_close_matches(word, [str(c) for c in candidates], n=1, cutoff=0.6)
    return f" (did you mean {close[0]!r}?)" if close else ""
