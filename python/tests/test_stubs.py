"""The package's type stubs and docstrings agree with its code.

- ``defocus/_defocus.pyi`` declares every function of the compiled module ``defocus._defocus``
  and nothing else, each with the parameters that ``inspect.signature`` reads from the
  compiled function (the ``#[pyfunction]`` signatures of python/src/lib.rs): the same names,
  order, kinds, which have defaults, and the same default where the stub writes a value
  instead of ``...``.
- Every public function and class of ``defocus`` has a NumPy-style docstring whose
  "Parameters" section documents each parameter of its signature, and no other, with
  ``default VALUE`` on the line of each parameter that has a default (the value the code
  has), and a "Returns" section where it returns something.
- A ``defocus/__init__.pyi``, if one is ever written, matches the package as the first does.

The stubs are read from the source tree (python/pysrc/defocus) when the tests run from a
checkout, else from the installed package.
"""

import ast
import inspect
from pathlib import Path

import pytest

import defocus
from defocus import _defocus

P = inspect.Parameter
SOURCE = Path(__file__).resolve().parents[1] / "pysrc" / "defocus"
INSTALLED = Path(defocus.__file__).resolve().parent


def stub_file(name):
    """The stub `name` of the source tree (what a change edits), else the installed one."""
    for folder in (SOURCE, INSTALLED):
        if (folder / name).is_file():
            return folder / name
    return None


# --- Stubs -----------------------------------------------------------------------------------


class Stub:
    """The top-level functions, classes and annotated names of a stub file."""

    def __init__(self, path):
        self.path = path
        tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
        self.functions = {}
        self.classes = {}
        self.values = set()
        for node in tree.body:
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                self.functions[node.name] = node
            elif isinstance(node, ast.ClassDef):
                self.classes[node.name] = node
            elif isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name):
                self.values.add(node.target.id)
            elif isinstance(node, ast.Assign):
                self.values.update(t.id for t in node.targets if isinstance(t, ast.Name))


def stub_parameters(fn, drop_first=False):
    """A stub function's parameters as (name, kind, default node or None), in order."""
    a = fn.args
    positional = [(p, P.POSITIONAL_ONLY) for p in a.posonlyargs]
    positional += [(p, P.POSITIONAL_OR_KEYWORD) for p in a.args]
    defaults = [None] * (len(positional) - len(a.defaults)) + list(a.defaults)
    params = [(p.arg, kind, d) for (p, kind), d in zip(positional, defaults)]
    if a.vararg is not None:
        params.append((a.vararg.arg, P.VAR_POSITIONAL, None))
    params += [(p.arg, P.KEYWORD_ONLY, d) for p, d in zip(a.kwonlyargs, a.kw_defaults)]
    if a.kwarg is not None:
        params.append((a.kwarg.arg, P.VAR_KEYWORD, None))
    return params[1:] if drop_first else params


def shown(params):
    """(name, kind, has_default) triples as a signature's text: ``(a, b=..., *, c)``."""
    out, star = [], False
    for i, (name, kind, has_default) in enumerate(params):
        if kind == P.KEYWORD_ONLY and not star:
            out.append("*")
        if kind in (P.VAR_POSITIONAL, P.KEYWORD_ONLY):
            star = True
        prefix = {P.VAR_POSITIONAL: "*", P.VAR_KEYWORD: "**"}.get(kind, "")
        out.append(prefix + name + ("=..." if has_default else ""))
        following = params[i + 1][1] if i + 1 < len(params) else None
        if kind == P.POSITIONAL_ONLY and following != P.POSITIONAL_ONLY:
            out.append("/")
    return "(" + ", ".join(out) + ")"


def stub_mismatches(label, runtime, stub_params):
    """How the stub's parameters differ from the runtime signature's: [] when they agree."""
    want = [(p.name, p.kind, p.default is not p.empty) for p in runtime.parameters.values()]
    got = [(name, kind, d is not None) for name, kind, d in stub_params]
    if want != got:
        i = next((i for i, (w, g) in enumerate(zip(want, got)) if w != g), min(len(want), len(got)))
        first = (
            f"parameter {i + 1}: the stub has {shown(got[i : i + 1]) if i < len(got) else 'none'}, "
            f"the code {shown(want[i : i + 1]) if i < len(want) else 'none'}"
        )
        return [f"{label}: the stub has {shown(got)}, the code {shown(want)} ({first})"]
    problems = []
    for p, (name, _, d) in zip(runtime.parameters.values(), stub_params):
        if d is None or (isinstance(d, ast.Constant) and d.value is Ellipsis):
            continue
        if p.default is Ellipsis:
            continue  # PyO3 writes a default it cannot show as a Python literal as `...`
        try:
            value = ast.literal_eval(d)
        except ValueError:
            continue  # a default the stub writes as an expression: only its presence is checked
        if value != p.default:
            problems.append(
                f"{label}: the stub's default of {name} is {value!r}, the code's {p.default!r}"
            )
    return problems


def runtime_signature(label, fn):
    """``inspect.signature(fn)``; a failure, naming `label`, for a compiled function without a
    text signature (PyO3 writes one from ``#[pyo3(signature = (...))]`` or the Rust parameters)."""
    if not inspect.isfunction(fn) and getattr(fn, "__text_signature__", None) is None:
        pytest.fail(
            f"{label} has no __text_signature__, so its parameters cannot be read: give it "
            "#[pyo3(signature = (...))] in python/src/lib.rs"
        )
    try:
        return inspect.signature(fn)
    except (TypeError, ValueError) as e:
        pytest.fail(f"{label}: inspect.signature cannot read its parameters: {e}")


# --- The compiled module and _defocus.pyi -----------------------------------------------------


def compiled_names():
    names = set(getattr(_defocus, "__all__", ()))
    names.update(n for n in dir(_defocus) if not n.startswith("_"))
    return sorted(names)


COMPILED_FUNCTIONS = [n for n in compiled_names() if callable(getattr(_defocus, n))]
COMPILED_VALUES = [n for n in compiled_names() if not callable(getattr(_defocus, n))]


@pytest.fixture(scope="module")
def native_stub():
    path = stub_file("_defocus.pyi")
    assert path is not None, f"no _defocus.pyi in {SOURCE} or {INSTALLED}"
    return Stub(path)


def test_the_compiled_module_has_functions():
    # Guards the tests below, which would pass on a module whose functions were not found.
    assert {"blur", "render", "compare"} <= set(COMPILED_FUNCTIONS), COMPILED_FUNCTIONS


def test_every_compiled_function_has_a_stub_and_every_stub_a_function(native_stub):
    compiled, stubbed = set(COMPILED_FUNCTIONS), set(native_stub.functions)
    assert not compiled - stubbed, (
        f"functions of defocus._defocus without a stub in {native_stub.path}: "
        f"{sorted(compiled - stubbed)}"
    )
    assert not stubbed - compiled, (
        f"stubs in {native_stub.path} of functions that defocus._defocus does not have: "
        f"{sorted(stubbed - compiled)}"
    )
    missing = set(COMPILED_VALUES) - native_stub.values
    assert not missing, f"attributes of defocus._defocus not declared in the stub: {sorted(missing)}"


@pytest.mark.parametrize("name", COMPILED_FUNCTIONS)
def test_the_stub_of_each_compiled_function_has_its_parameters(native_stub, name):
    if name not in native_stub.functions:
        pytest.skip(f"{name} has no stub (reported by the test above)")
    runtime = runtime_signature(f"defocus._defocus.{name}", getattr(_defocus, name))
    problems = stub_mismatches(
        f"defocus._defocus.{name}", runtime, stub_parameters(native_stub.functions[name])
    )
    assert not problems, "\n".join(problems)


# --- Docstrings of the public package ---------------------------------------------------------


def public_objects():
    """(label, object) of every public function and class of ``defocus``: those of
    ``__all__``, and any other defined in the package whose name does not start with ``_``."""
    names = set(defocus.__all__)
    names.update(n for n in dir(defocus) if not n.startswith("_"))
    found = []
    for name in sorted(names):
        obj = getattr(defocus, name)
        if not (inspect.isfunction(obj) or inspect.isclass(obj)):
            continue
        if not getattr(obj, "__module__", "").startswith("defocus"):
            continue  # imported from elsewhere (typing, numpy)
        found.append((f"defocus.{name}", obj))
    return found


def documented_callables():
    """(label, callable, docstring, signature) of each public function, each public class
    (its docstring documents ``__init__``'s parameters) and each public method, ``__call__``
    included."""
    out = []
    for label, obj in public_objects():
        if inspect.isclass(obj):
            out.append((label, obj, inspect.getdoc(obj), inspect.signature(obj)))
            for name, member in sorted(vars(obj).items()):
                if inspect.isfunction(member) and (not name.startswith("_") or name == "__call__"):
                    sig = inspect.signature(member)
                    sig = sig.replace(parameters=list(sig.parameters.values())[1:])  # self
                    out.append((f"{label}.{name}", member, inspect.getdoc(member), sig))
        else:
            out.append((label, obj, inspect.getdoc(obj), inspect.signature(obj)))
    return out


def sections(doc):
    """A NumPy-style docstring's sections: {heading: [lines]}, a heading being an unindented
    line underlined with dashes."""
    lines = inspect.cleandoc(doc).splitlines()
    found, current, i = {}, None, 0
    while i < len(lines):
        line = lines[i]
        under = lines[i + 1].strip() if i + 1 < len(lines) else ""
        if line.strip() and not line[0].isspace() and len(under) >= 3 and set(under) == {"-"}:
            current = line.strip()
            found[current] = []
            i += 2
            continue
        if current is not None:
            found[current].append(line)
        i += 1
    return found


def documented_parameters(lines):
    """{name: type text} of a Parameters section: its unindented lines, ``name : type`` or
    ``**name``; ``a, b : type`` documents both."""
    params = {}
    for line in lines:
        if not line.strip() or line[0].isspace():
            continue
        head, _, kind = line.partition(" : ")
        for name in head.rstrip(" :").split(","):
            params[name.strip().lstrip("*")] = kind.strip()
    return params


def documented_default(kind):
    """The value after the last ``default`` of a parameter's type text, or a reason it has none."""
    at = kind.rfind("default")
    if at < 0:
        return None, "no 'default VALUE'"
    text = kind[at + len("default") :].strip().lstrip(":=").strip()
    try:
        return ast.literal_eval(text), None
    except (ValueError, SyntaxError):
        return None, f"'default {text}' is not a Python literal"


DOCUMENTED = documented_callables()


def test_the_package_has_public_functions():
    labels = {label for label, *_ in DOCUMENTED}
    assert {"defocus.blur", "defocus.render", "defocus.RandomDefocus"} <= labels, labels


@pytest.mark.parametrize("label, obj, doc, sig", DOCUMENTED, ids=[d[0] for d in DOCUMENTED])
def test_each_public_function_documents_its_parameters(label, obj, doc, sig):
    assert doc and doc.strip(), f"{label} has no docstring"
    assert doc.splitlines()[0].strip(), f"{label}: the docstring starts with an empty line"
    found = sections(doc)
    params = list(sig.parameters.values())
    if params:
        assert "Parameters" in found, (
            f"{label}: no 'Parameters' section (a line 'Parameters' underlined with dashes)"
        )
        documented = documented_parameters(found["Parameters"])
        names = [p.name for p in params]
        assert not set(names) - set(documented), (
            f"{label}: parameters not in its 'Parameters' section: "
            f"{[n for n in names if n not in documented]}"
        )
        assert not set(documented) - set(names), (
            f"{label}: its 'Parameters' section documents parameters it does not have: "
            f"{sorted(set(documented) - set(names))}"
        )
        problems = []
        for p in params:
            if p.default is p.empty:
                continue
            value, why = documented_default(documented[p.name])
            if why is not None:
                problems.append(f"{p.name}: the code's default is {p.default!r}, the docstring has {why}")
            elif value != p.default:
                problems.append(f"{p.name}: the docstring says default {value!r}, the code has {p.default!r}")
        assert not problems, f"{label}:\n" + "\n".join(problems)
    returns = sig.return_annotation
    if not inspect.isclass(obj) and returns not in (None, "None", sig.empty):
        assert "Returns" in found, f"{label}: no 'Returns' section"


# --- A stub of the public package, if there is one --------------------------------------------


def test_a_stub_of_the_package_matches_it():
    path = stub_file("__init__.pyi")
    if path is None:
        pytest.skip("no defocus/__init__.pyi: the package's own annotations are its types (py.typed)")
    stub = Stub(path)
    problems = []
    for label, obj in public_objects():
        name = label.split(".", 1)[1]
        if inspect.isfunction(obj):
            if name not in stub.functions:
                problems.append(f"{label}: no stub in {path}")
                continue
            problems += stub_mismatches(
                label, inspect.signature(obj), stub_parameters(stub.functions[name])
            )
        else:
            if name not in stub.classes:
                problems.append(f"{label}: no stub class in {path}")
                continue
            methods = {
                n.name: n for n in stub.classes[name].body if isinstance(n, ast.FunctionDef)
            }
            for member_name, member in sorted(vars(obj).items()):
                if not inspect.isfunction(member):
                    continue
                if member_name.startswith("_") and member_name not in ("__init__", "__call__"):
                    continue
                if member_name not in methods:
                    problems.append(f"{label}.{member_name}: no stub in {path}")
                    continue
                sig = inspect.signature(member)
                sig = sig.replace(parameters=list(sig.parameters.values())[1:])  # self
                problems += stub_mismatches(
                    f"{label}.{member_name}",
                    sig,
                    stub_parameters(methods[member_name], drop_first=True),
                )
    for name in sorted(set(stub.functions) | set(stub.classes)):
        if not name.startswith("_") and not hasattr(defocus, name):
            problems.append(f"{path} declares {name}, which defocus does not have")
    assert not problems, "\n".join(problems)
