"""hapticpd: a Python client of the hapticpd gRPC API (proto/hapticpd/v1).

    import hapticpd
    with hapticpd.connect("127.0.0.1:50051") as c:
        c.create_scene("lab", "a box to press")
        c.add_shape("lab", "box:0.05,0.05,0.05", body_id="box")
        for u in c.couple("lab", [(0, 0, 0.07), (0, 0, 0.05)]):
            print(u.sequence, hapticpd.vec3(u.force))

The message classes are the generated ones, importable as
`hapticpd.v1.types_pb2`, `hapticpd.v1.scene_pb2`, `hapticpd.v1.haptic_pb2`
(and their `*_pb2_grpc` stubs). They are generated from proto/ at build time
(CMake target `hapticpd_python`) into <build>/client/python/gen, which must be
on sys.path next to client/python (client/python/README.md).
"""
import pkgutil as _pkgutil

# The generated modules live in <gen>/hapticpd/v1/ (protoc mirrors the proto
# package); <gen>/hapticpd has no __init__.py, so it is a namespace portion
# that this package takes into its own path. Order on sys.path is irrelevant.
__path__ = _pkgutil.extend_path(__path__, __name__)

try:
    from .v1 import types_pb2, scene_pb2, haptic_pb2  # noqa: F401
    from .v1 import scene_pb2_grpc, haptic_pb2_grpc  # noqa: F401
except ImportError as _e:  # pragma: no cover - depends on the installation
    raise ImportError(
        "hapticpd: the generated modules hapticpd.v1.*_pb2 were not found or did not "
        "import (%s). Build them (cmake --build build/release --target hapticpd_python) "
        "and put build/release/client/python/gen on PYTHONPATH next to client/python, "
        "or run build/release/client/python/hapticpd-python; they need Debian's "
        "python3-grpcio and python3-protobuf (/usr/bin/python3)." % (_e,)) from _e

from ._client import (  # noqa: E402
    Client,
    Coupling,
    HapticpdError,
    connect,
    material,
    pose,
    twist,
    vec3,
)

__all__ = [
    "Client",
    "Coupling",
    "HapticpdError",
    "connect",
    "material",
    "pose",
    "twist",
    "vec3",
    "types_pb2",
    "scene_pb2",
    "haptic_pb2",
    "scene_pb2_grpc",
    "haptic_pb2_grpc",
]
