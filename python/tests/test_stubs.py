"""The type stubs (gsenc/__init__.pyi, gsenc/_gsenc.pyi) against what the
package and its native module take. A type checker and an editor believe the
stubs; nothing at run time reads them. So each stub function and method is
compared with `inspect.signature` of the object it describes: the same
parameters in the same order, each positional or keyword-only as there, and
the same defaults; the stubs name every public function, class, method and
property, and no other."""

import __future__
import ast
import inspect
import pathlib
import types

import pytest

import gsenc
from gsenc import _gsenc

PACKAGE = pathlib.Path(gsenc.__file__).parent
STUBS = [("__init__.pyi", gsenc), ("_gsenc.pyi", _gsenc)]
# Names a stub takes from elsewhere or that are not functions.
NOT_CALLABLES = {"HAS_HDF5", "PRIMITIVE_DTYPE", "__version__"}


def _is_property(node):
    return any(isinstance(d, ast.Name) and d.id == "property" for d in node.decorator_list)


def stub_entries(name):
    """{qualified name: FunctionDef} of a stub's functions and methods,
    {class: set of property names}, and the names it re-exports."""
    tree = ast.parse((PACKAGE / name).read_text())
    functions, properties, reexported = {}, {}, set()
    for node in tree.body:
        if isinstance(node, ast.ImportFrom) and node.level == 1:
            reexported |= {a.asname for a in node.names if a.asname == a.name}
        elif isinstance(node, ast.FunctionDef):
            functions[node.name] = node
        elif isinstance(node, ast.ClassDef):
            properties[node.name] = set()
            for m in node.body:
                if isinstance(m, ast.FunctionDef):
                    if _is_property(m):
                        properties[node.name].add(m.name)
                    else:
                        functions[f"{node.name}.{m.name}"] = m
    return functions, properties, reexported


def stub_parameters(fn):
    """[(name, kind, default)] of a stub function, `self` left out; a
    missing default is inspect.Parameter.empty."""
    a = fn.args
    out = []
    positional = a.posonlyargs + a.args
    defaults = [None] * (len(positional) - len(a.defaults)) + list(a.defaults)
    for i, (arg, d) in enumerate(zip(positional, defaults)):
        kind = "POSITIONAL_ONLY" if i < len(a.posonlyargs) else "POSITIONAL_OR_KEYWORD"
        out.append((arg.arg, kind, inspect.Parameter.empty if d is None else ast.literal_eval(d)))
    for arg, d in zip(a.kwonlyargs, a.kw_defaults):
        out.append((arg.arg, "KEYWORD_ONLY", inspect.Parameter.empty if d is None else ast.literal_eval(d)))
    return [p for p in out if p[0] != "self"]


def runtime_parameters(obj):
    """The same of the object itself (a class: its constructor)."""
    params = inspect.signature(obj).parameters.values()
    return [(p.name, p.kind.name, p.default) for p in params if p.name != "self"]


def resolve(module, qualified):
    """The object a stub entry describes; a class's `__init__` is described
    by the class's own signature."""
    obj = module
    for part in qualified.removesuffix(".__init__").split("."):
        obj = getattr(obj, part)
    return obj


def cases():
    for stub, module in STUBS:
        functions, _, _ = stub_entries(stub)
        for name, node in functions.items():
            yield pytest.param(stub, module, name, node, id=f"{stub}:{name}")


@pytest.mark.parametrize("stub,module,name,node", list(cases()))
def test_each_stub_signature_is_the_objects(stub, module, name, node):
    want = runtime_parameters(resolve(module, name))
    assert stub_parameters(node) == want, f"{stub}: {name}"


@pytest.mark.parametrize("stub,module", STUBS, ids=[s for s, _ in STUBS])
def test_the_stubs_name_every_public_name(stub, module):
    functions, properties, reexported = stub_entries(stub)
    public = {n for n, v in vars(module).items() if not n.startswith("_") and n not in NOT_CALLABLES and not inspect.ismodule(v) and not isinstance(v, __future__._Feature)}
    stubbed = {n for n in functions if "." not in n} | set(properties) | (reexported - NOT_CALLABLES)
    assert stubbed == public, f"{stub}: stubbed {sorted(stubbed)}, public {sorted(public)}"
    for cls, props in properties.items():
        obj = getattr(module, cls)
        methods = {n.split(".", 1)[1] for n in functions if n.startswith(cls + ".")}
        members = {n for n in vars(obj) if not n.startswith("_")}
        assert {m for m in methods if not m.startswith("_")} | props == members, f"{stub}: {cls}'s methods and properties"
        for p in props:
            assert isinstance(vars(obj)[p], (property, types.GetSetDescriptorType)), f"{stub}: {cls}.{p} is stubbed as a property"


def test_a_changed_signature_is_found():
    """The comparison can fail: a default, an order, a keyword-only marker."""
    good = ast.parse("def f(a, b=None, *, c='auto'): ...").body[0]

    def f(a, b=None, *, c="auto"):
        pass

    assert stub_parameters(good) == runtime_parameters(f)
    for bad in ["def f(a, b=0, *, c='auto'): ...", "def f(b=None, a=None, *, c='auto'): ...", "def f(a, b=None, c='auto'): ...", "def f(a, b=None): ..."]:
        assert stub_parameters(ast.parse(bad).body[0]) != runtime_parameters(f), bad
