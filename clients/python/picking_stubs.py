"""Generates and imports the Python gRPC stubs of the picking system from proto/.

The stubs are generated with grpc_tools (Debian: python3-grpc-tools) into a cache folder
the first time they are needed, so the client always matches the contracts of the checkout
it runs from. Use Debian's interpreter (/usr/bin/python3), which has python3-grpcio.
"""

import hashlib
import importlib
import os
import pathlib
import shutil
import sys
import tempfile

PROTO_ROOT = pathlib.Path(__file__).resolve().parents[2] / "proto"

# The vendored gRPC contracts live under proto/grpc/ (health/v1, reflection/v1); generated
# as is, their modules "grpc.health.v1" and "grpc.reflection.v1" would clash with grpcio's
# own "grpc" package. They are generated as "grpc_health_vendored.v1.health_pb2" and
# "grpc_reflection_vendored.v1.reflection_pb2" instead (same proto packages, same wire
# format).
HEALTH_MODULE = "grpc_health_vendored.v1"
REFLECTION_MODULE = "grpc_reflection_vendored.v1"
_RENAMES = {"grpc/health/v1/health.proto": "grpc_health_vendored/v1/health.proto",
            "grpc/reflection/v1/reflection.proto":
                "grpc_reflection_vendored/v1/reflection.proto"}


def _proto_files():
    return sorted(p for p in PROTO_ROOT.rglob("*.proto"))


def _digest(files):
    h = hashlib.sha256()
    for f in files:
        h.update(str(f.relative_to(PROTO_ROOT)).encode())
        h.update(f.read_bytes())
    return h.hexdigest()[:16]


def ensure_stubs(out_dir=None):
    """Generates the stubs (if the protos changed) and puts them on sys.path.

    Returns the folder holding the generated modules.
    """
    from grpc_tools import protoc  # Imported late: only needed when generating.
    import grpc_tools

    files = _proto_files()
    if not files:
        raise RuntimeError(f"no .proto files under {PROTO_ROOT}")
    cache = pathlib.Path(out_dir or os.environ.get(
        "PICKING_PY_STUBS", pathlib.Path.home() / ".cache" / "picking" / "pystubs"))
    target = cache / _digest(files)
    if not (target / ".complete").exists():
        target.mkdir(parents=True, exist_ok=True)
        well_known = pathlib.Path(grpc_tools.__file__).parent / "_proto"
        with tempfile.TemporaryDirectory() as staging:
            staged = []
            for f in files:
                rel = str(f.relative_to(PROTO_ROOT))
                dest = pathlib.Path(staging) / _RENAMES.get(rel, rel)
                dest.parent.mkdir(parents=True, exist_ok=True)
                shutil.copyfile(f, dest)
                staged.append(_RENAMES.get(rel, rel))
            args = ["grpc_tools.protoc", f"-I{staging}", f"-I{well_known}",
                    f"--python_out={target}", f"--grpc_python_out={target}"] + staged
            if protoc.main(args) != 0:
                raise RuntimeError("grpc_tools.protoc failed on " + str(PROTO_ROOT))
        # No __init__.py files: the generated folders stay namespace packages, so that
        # "google.rpc" here and protobuf's "google.protobuf" both import.
        (target / ".complete").touch()
    if str(target) not in sys.path:
        sys.path.insert(0, str(target))
    return target


def load(module):
    """Imports a generated module, e.g. load("picking.planner.v1.planner_pb2")."""
    ensure_stubs()
    return importlib.import_module(module)
