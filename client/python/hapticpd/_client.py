"""The client object behind hapticpd.connect (see client/python/README.md)."""
import os
import re
import threading
import time
import uuid

import grpc
from google.protobuf import json_format

from .v1 import haptic_pb2, haptic_pb2_grpc, scene_pb2, scene_pb2_grpc, types_pb2

DEFAULT_SERVER = "127.0.0.1:50051"

_MESH_FORMATS = {
    ".obj": types_pb2.MESH_FORMAT_OBJ,
    ".stl": types_pb2.MESH_FORMAT_STL,
    ".ply": types_pb2.MESH_FORMAT_PLY,
    ".off": types_pb2.MESH_FORMAT_OFF,
}

_MODES = {
    None: haptic_pb2.PD_MODE_UNSPECIFIED,  # the scene's declared mode
    "scene": haptic_pb2.PD_MODE_UNSPECIFIED,
    "none": haptic_pb2.PD_MODE_NONE,
    "pdt": haptic_pb2.PD_MODE_PDT,
    "pdg": haptic_pb2.PD_MODE_PDG,
}

# What may travel as a metadata value untouched: the scene-id alphabet of the
# API. Other ids are still sent in the request (the server names the field).
_METADATA_ID = re.compile(r"[A-Za-z0-9_.-]{1,64}")

SCENE_METADATA_KEY = "x-hapticpd-scene"


class HapticpdError(Exception):
    """A call the server (or gRPC) ended with a status other than OK.

    `code` is the status code's name ("INVALID_ARGUMENT", "NOT_FOUND", ...),
    `message` the server's message (it names the field), `grpc_code` the
    grpc.StatusCode. str(e) is "CODE: message", as the hapticpd command prints.
    """

    def __init__(self, code, message, grpc_code=None):
        self.code = code
        self.message = message
        self.grpc_code = grpc_code
        super().__init__("%s: %s" % (code, message))


def _error(err):
    code = err.code() if callable(getattr(err, "code", None)) else None
    details = err.details() if callable(getattr(err, "details", None)) else None
    name = code.name if code is not None else "UNKNOWN"
    return HapticpdError(name, details if details is not None else str(err), code)


# --- values -----------------------------------------------------------------

def pose(x=0.0, y=0.0, z=0.0, qw=1.0, qx=0.0, qy=0.0, qz=0.0):
    """A Pose: position in metres, orientation as a unit quaternion (w, x, y, z).

    The quaternion is sent as given (the server normalises one within 1e-3 of
    unit norm and rejects others with INVALID_ARGUMENT naming the field).
    """
    return types_pb2.Pose(
        position=types_pb2.Vec3(x=x, y=y, z=z),
        orientation=types_pb2.Quaternion(w=qw, x=qx, y=qy, z=qz))


def twist(vx=0.0, vy=0.0, vz=0.0, wx=0.0, wy=0.0, wz=0.0):
    """A Twist: linear (m/s) and angular (rad/s) velocity in the world frame."""
    return types_pb2.Twist(linear=types_pb2.Vec3(x=vx, y=vy, z=vz),
                           angular=types_pb2.Vec3(x=wx, y=wy, z=wz))


def material(stiffness=1000.0, rotational_stiffness=0.05, damping=0.0,
             static_friction=0.0, dynamic_friction=0.0):
    """A Material; the defaults are the server's defaults for an absent one."""
    return types_pb2.Material(stiffness=stiffness, rotational_stiffness=rotational_stiffness,
                              damping=damping, static_friction=static_friction,
                              dynamic_friction=dynamic_friction)


def vec3(v):
    """(x, y, z) of a Vec3 message, e.g. vec3(update.force)."""
    return (v.x, v.y, v.z)


def _to_pose(p):
    if p is None:
        return pose()
    if isinstance(p, types_pb2.Pose):
        return p
    values = tuple(p)
    if len(values) not in (3, 7):
        raise TypeError("a pose is (x, y, z), (x, y, z, qw, qx, qy, qz) or a Pose, got %d numbers"
                        % len(values))
    return pose(*(float(v) for v in values))


def _to_twist(v):
    if v is None or isinstance(v, types_pb2.Twist):
        return v
    values = tuple(v)
    if len(values) not in (3, 6):
        raise TypeError("a velocity is (vx, vy, vz), (vx, vy, vz, wx, wy, wz) or a Twist, "
                        "got %d numbers" % len(values))
    return twist(*(float(x) for x in values))


def _to_material(m):
    if m is None or isinstance(m, types_pb2.Material):
        return m
    if isinstance(m, dict):
        return material(**m)
    raise TypeError("material: a Material, a dict of its fields, or None")


def _to_config(c):
    if c is None or isinstance(c, haptic_pb2.SceneConfig):
        return c
    if isinstance(c, dict):
        return json_format.ParseDict(c, haptic_pb2.SceneConfig())
    raise TypeError("config: a SceneConfig, a dict of its fields (json_format names), or None")


def _to_mode(mode):
    if isinstance(mode, int):
        return mode
    key = mode.lower() if isinstance(mode, str) else mode
    if key not in _MODES:
        raise ValueError("mode: one of 'pdt', 'pdg', 'none' or None (the scene's), got %r" % (mode,))
    return _MODES[key]


def _inline_mesh(vertices, triangles):
    flat_v = []
    for v in vertices:
        if isinstance(v, (int, float)):
            flat_v.append(float(v))
        else:
            flat_v.extend(float(x) for x in v)
    flat_t = []
    for t in triangles:
        if isinstance(t, int):
            flat_t.append(t)
        else:
            flat_t.extend(int(i) for i in t)
    return types_pb2.InlineMesh(vertices=flat_v, triangles=flat_t)


def _request_id(given):
    return given if given is not None else str(uuid.uuid4())


# --- streams ----------------------------------------------------------------

class _Stream:
    """Iterates a server stream, turning gRPC errors into HapticpdError."""

    def __init__(self):
        self._call = None
        self._closed = False
        self._local_error = None

    def __iter__(self):
        return self

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False

    def __del__(self):
        try:
            self.close()
        except Exception:  # interpreter shutdown
            pass

    def close(self):
        """Ends the stream (cancels the call); iteration then stops."""
        self._closed = True
        if self._call is not None:
            self._call.cancel()
        self._finished()

    cancel = close

    def _finished(self):
        pass

    def _next_message(self):
        if self._call is None:
            raise StopIteration
        try:
            return next(self._call)
        except StopIteration:
            self._finished()
            raise
        except grpc.RpcError as e:
            self._finished()
            if self._local_error is not None:
                raise self._local_error from None
            if self._closed and e.code() == grpc.StatusCode.CANCELLED:
                raise StopIteration from None
            raise _error(e) from e


class Watch(_Stream):
    """Iterator of SceneEvents (a snapshot first, then changes and poses)."""

    def __init__(self, call):
        super().__init__()
        self._call = call

    def __next__(self):
        return self._next_message()


class Coupling(_Stream):
    """A device session: iterate it for ContactUpdates.

    `welcome` holds the server's Welcome once the first update has been read.
    `sent` and `received` count poses sent and updates yielded. With
    lockstep=True (the default) a pose is sent only once the previous one is
    answered, so every pose gets its own answer; with lockstep=False the
    poses are sent as fast as the iterator gives them and the server answers
    the newest (superseded ones are counted in `poses_superseded`).
    """

    def __init__(self, stub, hello, poses, lockstep, metadata, timeout):
        super().__init__()
        self.welcome = None
        self.sent = 0
        self.received = 0
        self._poses = iter(poses)
        self._lockstep = lockstep
        self._cv = threading.Condition()
        self._answered = 0
        self._done = False
        self._call = stub.Couple(self._requests(hello), metadata=metadata, timeout=timeout)

    def _requests(self, hello):
        yield haptic_pb2.CoupleRequest(hello=hello)
        seq = 0
        while True:
            if self._lockstep and seq > 0:
                with self._cv:
                    while self._answered < seq and not self._done:
                        self._cv.wait(0.25)
            if self._done:
                return
            try:
                p = next(self._poses)
                msg = haptic_pb2.CoupleRequest(pose=haptic_pb2.ProbePose(
                    sequence=seq + 1, pose=_to_pose(p), client_time_ns=time.monotonic_ns()))
            except StopIteration:
                return  # half-close: the server still sends the last answer
            except Exception as e:  # a bad pose from the caller's iterator
                self._local_error = e
                raise
            seq += 1
            self.sent = seq
            yield msg

    def _finished(self):
        with self._cv:
            self._done = True
            self._cv.notify_all()

    def __next__(self):
        while True:
            resp = self._next_message()
            if resp.HasField("welcome"):
                self.welcome = resp.welcome
                continue
            u = resp.update
            with self._cv:
                if u.sequence > self._answered:
                    self._answered = u.sequence
                self._cv.notify_all()
            self.received += 1
            return u


# --- the client ---------------------------------------------------------------

class Client:
    """A connection to a hapticpd server; use hapticpd.connect()."""

    def __init__(self, server=None, token=None, tls_ca=None, tls=False, timeout=30.0,
                 options=None):
        self.server = server or os.environ.get("HAPTICPD_SERVER") or DEFAULT_SERVER
        if token is None:
            token = os.environ.get("HAPTICPD_TOKEN") or None
        self._token = token
        self.timeout = timeout
        opts = [("grpc.max_receive_message_length", -1)]
        opts.extend(options or [])
        if tls_ca is not None or tls:
            root = None
            if tls_ca is not None:
                with open(tls_ca, "rb") as f:
                    root = f.read()
            creds = grpc.ssl_channel_credentials(root_certificates=root)
            self._channel = grpc.secure_channel(self.server, creds, options=opts)
        else:
            self._channel = grpc.insecure_channel(self.server, options=opts)
        self._scenes = scene_pb2_grpc.SceneServiceStub(self._channel)
        self._haptic = haptic_pb2_grpc.HapticServiceStub(self._channel)

    # -- plumbing
    def close(self):
        self._channel.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False

    def metadata(self, scene=None):
        """The call metadata: `authorization: Bearer TOKEN` when a token is
        set, and `x-hapticpd-scene: ID` for a scene-scoped call."""
        md = []
        if self._token:
            value = self._token if self._token.startswith("Bearer ") else "Bearer " + self._token
            md.append(("authorization", value))
        if isinstance(scene, str) and _METADATA_ID.fullmatch(scene):
            md.append((SCENE_METADATA_KEY, scene))
        return md

    def _deadline(self, timeout):
        return self.timeout if timeout is None else timeout

    def _unary(self, method, request, scene=None, timeout=None):
        try:
            return method(request, metadata=self.metadata(scene), timeout=self._deadline(timeout))
        except grpc.RpcError as e:
            raise _error(e) from e

    # -- scenes
    def list_scenes(self, timeout=None):
        """[SceneSummary]"""
        return list(self._unary(self._scenes.ListScenes, scene_pb2.ListScenesRequest(),
                                timeout=timeout).scenes)

    def create_scene(self, scene_id, description="", config=None, request_id=None, timeout=None):
        """Creates a scene; config: SceneConfig or a dict of its fields. -> SceneSummary"""
        req = scene_pb2.CreateSceneRequest(scene_id=scene_id, description=description,
                                           request_id=_request_id(request_id))
        cfg = _to_config(config)
        if cfg is not None:
            req.config.CopyFrom(cfg)
        return self._unary(self._scenes.CreateScene, req, scene_id, timeout)

    def get_scene(self, scene_id, include_meshes=False, timeout=None):
        """-> Scene (bodies with poses, materials, mesh info; meshes if asked)"""
        return self._unary(self._scenes.GetScene,
                           scene_pb2.GetSceneRequest(scene_id=scene_id,
                                                     include_meshes=include_meshes),
                           scene_id, timeout)

    def delete_scene(self, scene_id, request_id=None, timeout=None):
        self._unary(self._scenes.DeleteScene,
                    scene_pb2.DeleteSceneRequest(scene_id=scene_id,
                                                 request_id=_request_id(request_id)),
                    scene_id, timeout)

    # -- bodies
    def _header(self, scene, pose_, body_id, material_, movable, velocity, label, request_id):
        spec = scene_pb2.BodySpec(body_id=body_id or "", pose=_to_pose(pose_),
                                  movable=movable, label=label or "")
        m = _to_material(material_)
        if m is not None:
            spec.material.CopyFrom(m)
        v = _to_twist(velocity)
        if v is not None:
            spec.velocity.CopyFrom(v)
        return scene_pb2.AddBodyHeader(scene_id=scene, spec=spec,
                                       request_id=_request_id(request_id))

    def _add_body(self, scene, requests, timeout):
        try:
            return self._scenes.AddBody(requests, metadata=self.metadata(scene),
                                        timeout=self._deadline(timeout))
        except grpc.RpcError as e:
            raise _error(e) from e

    def add_shape(self, scene, shape, pose=None, body_id=None, material=None, movable=False,
                  velocity=None, label=None, request_id=None, timeout=None):
        """Adds a built-in shape ("box:0.05,0.05,0.05", "stick", ...). -> Body"""
        h = self._header(scene, pose, body_id, material, movable, velocity, label, request_id)
        h.shape = shape
        return self._add_body(scene, iter([scene_pb2.AddBodyRequest(header=h)]), timeout)

    def add_mesh(self, scene, vertices, triangles, pose=None, body_id=None, material=None,
                 movable=False, velocity=None, label=None, request_id=None, timeout=None):
        """Adds an inline mesh: vertices as (x, y, z) triples or a flat list,
        triangles as index triples (counter-clockwise seen from outside). -> Body"""
        h = self._header(scene, pose, body_id, material, movable, velocity, label, request_id)
        h.inline_mesh.CopyFrom(_inline_mesh(vertices, triangles))
        return self._add_body(scene, iter([scene_pb2.AddBodyRequest(header=h)]), timeout)

    def add_mesh_file(self, scene, path, pose=None, body_id=None, material=None, movable=False,
                      velocity=None, label=None, mesh_format=None, chunk_size=1 << 16,
                      request_id=None, timeout=None):
        """Uploads an OBJ/STL/PLY/OFF file in chunks (format from the
        extension unless mesh_format is given; total_bytes = the file size).
        -> Body"""
        if mesh_format is None:
            ext = os.path.splitext(path)[1].lower()
            if ext not in _MESH_FORMATS:
                raise ValueError("%s: unknown mesh extension %r (.obj, .stl, .ply, .off); pass "
                                 "mesh_format" % (path, ext))
            mesh_format = _MESH_FORMATS[ext]
        elif isinstance(mesh_format, str):
            key = "." + mesh_format.lower().lstrip(".")
            if key not in _MESH_FORMATS:
                raise ValueError("mesh_format: obj, stl, ply or off, got %r" % (mesh_format,))
            mesh_format = _MESH_FORMATS[key]
        if chunk_size <= 0:
            raise ValueError("chunk_size must be positive")
        f = open(path, "rb")  # raises here (locally) when the file is missing
        try:
            size = os.fstat(f.fileno()).st_size
            h = self._header(scene, pose, body_id, material, movable, velocity,
                             label if label is not None else os.path.basename(path), request_id)
            h.format = mesh_format
            h.total_bytes = size

            def requests():
                yield scene_pb2.AddBodyRequest(header=h)
                while True:
                    chunk = f.read(chunk_size)
                    if not chunk:
                        return
                    yield scene_pb2.AddBodyRequest(chunk=chunk)

            return self._add_body(scene, requests(), timeout)
        finally:
            f.close()

    def move_body(self, scene, body_id, pose, velocity=None, request_id=None, timeout=None):
        """Sets a movable body's pose (and velocity). -> the scene's new revision"""
        req = scene_pb2.MoveBodyRequest(scene_id=scene, body_id=body_id, pose=_to_pose(pose),
                                        request_id=_request_id(request_id))
        v = _to_twist(velocity)
        if v is not None:
            req.velocity.CopyFrom(v)
        return self._unary(self._scenes.MoveBody, req, scene, timeout).revision

    def remove_body(self, scene, body_id, request_id=None, timeout=None):
        """-> the scene's new revision"""
        req = scene_pb2.RemoveBodyRequest(scene_id=scene, body_id=body_id,
                                          request_id=_request_id(request_id))
        return self._unary(self._scenes.RemoveBody, req, scene, timeout).revision

    # -- streams
    def watch(self, scene, rate_hz=30, include_meshes=False, timeout=None):
        """Iterator of SceneEvents: a snapshot, then changes and pose frames.
        Ends with close(); timeout (s, default none) bounds the whole stream."""
        req = scene_pb2.WatchRequest(scene_id=scene, rate_hz=rate_hz,
                                     include_meshes=include_meshes)
        return Watch(self._scenes.Watch(req, metadata=self.metadata(scene), timeout=timeout))

    def couple(self, scene, poses, mode="pdt", probe_shape="sphere:0.01,2", probe_body_id=None,
               probe_mesh=None, material=None, max_rate_hz=0.0, client_name="hapticpd-python",
               lockstep=True, timeout=None):
        """A device session: sends a Hello, then the poses of the iterable
        (tuples (x, y, z) or (x, y, z, qw, qx, qy, qz), or Pose messages),
        and yields the ContactUpdates. The probe is probe_body_id (a body of
        the scene), probe_mesh ((vertices, triangles)) or probe_shape, in that
        order of precedence. -> Coupling (an iterator; .welcome, .close())"""
        hello = haptic_pb2.Hello(protocol_version=1, scene_id=scene, mode=_to_mode(mode),
                                 max_rate_hz=max_rate_hz, client_name=client_name)
        if probe_body_id is not None:
            hello.probe_body_id = probe_body_id
        elif probe_mesh is not None:
            hello.probe_mesh.CopyFrom(_inline_mesh(*probe_mesh))
        else:
            hello.probe_shape = probe_shape
        m = _to_material(material)
        if m is not None:
            hello.material.CopyFrom(m)
        return Coupling(self._haptic, hello, poses, lockstep, self.metadata(scene), timeout)


def connect(server=None, token=None, tls_ca=None, tls=False, timeout=30.0, options=None):
    """A Client of the server HOST:PORT (default $HAPTICPD_SERVER or
    127.0.0.1:50051). token: sent as `authorization: Bearer TOKEN` (default
    $HAPTICPD_TOKEN). tls_ca: a CA certificate file (PEM) for TLS; tls=True:
    TLS with the system's roots. timeout: seconds per unary call (None: no
    deadline). The channel connects lazily: an unreachable server shows as
    HapticpdError UNAVAILABLE on the first call."""
    return Client(server, token=token, tls_ca=tls_ca, tls=tls, timeout=timeout, options=options)

