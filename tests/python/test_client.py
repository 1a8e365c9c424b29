"""Tests of the Python client (client/python/hapticpd) against real
`hapticpd serve` processes, and of what it puts on the wire against a
recording gRPC server in this process.

Run by ctest (label `python`, tests/CMakeLists.txt) as
    /usr/bin/python3 -m unittest -v test_client
in tests/python, with PYTHONPATH=<build>/client/python/gen:client/python,
HAPTICPD_CLI=<build>/hapticpd and HAPTICPD_TESTDATA_DIR=tests/data.
Exits 77 (ctest: skipped) when the interpreter lacks Debian's python3-grpcio.
"""
import json
import os
import queue
import re
import subprocess
import sys
import tempfile
import threading
import unittest
from concurrent import futures

try:
    import grpc
    from google import protobuf
except ImportError as e:
    print("SKIP: %s lacks grpc/protobuf (%s); install Debian's python3-grpcio and "
          "python3-protobuf (docker/install-deps.sh)" % (sys.executable, e))
    raise SystemExit(77)
print("grpc %s, protobuf %s (%s)" % (grpc.__version__, protobuf.__version__, sys.executable))

import hapticpd
from hapticpd import HapticpdError
from hapticpd.v1 import haptic_pb2, scene_pb2, scene_pb2_grpc, types_pb2

CLI = os.environ.get("HAPTICPD_CLI", "")
TESTDATA = os.environ.get("HAPTICPD_TESTDATA_DIR",
                          os.path.join(os.path.dirname(__file__), "..", "data"))
LISTEN_RE = re.compile(r"listening on 127\.0\.0\.1:(\d+)")


def serve_flags():
    """--ephemeral when this `hapticpd serve` has it (no state kept on disk)."""
    out = subprocess.run([CLI, "serve", "--help"], stdout=subprocess.PIPE,
                         stderr=subprocess.STDOUT, text=True, timeout=30).stdout
    return ["--ephemeral"] if "--ephemeral" in out else []


class Server:
    """A `hapticpd serve --listen 127.0.0.1:0` child process; port from its log."""

    def __init__(self, *extra):
        if not CLI or not os.access(CLI, os.X_OK):
            raise RuntimeError("HAPTICPD_CLI (the hapticpd executable) is not set or not "
                               "executable: %r" % CLI)
        self.log = []
        self._port = queue.Queue()
        cmd = [CLI, "serve", "--listen", "127.0.0.1:0", "--status-interval", "3600"]
        cmd += serve_flags() + list(extra)
        self.proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                     text=True, errors="replace")
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()
        try:
            port = self._port.get(timeout=30)
        except queue.Empty:
            port = None
        if port is None:
            self.stop()
            raise RuntimeError("hapticpd serve did not report its port:\n" + "".join(self.log))
        self.address = "127.0.0.1:%d" % port

    def _read(self):
        for line in self.proc.stdout:
            self.log.append(line)
            m = LISTEN_RE.search(line)
            if m:
                self._port.put(int(m.group(1)))
        self._port.put(None)

    def stop(self):
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        self._reader.join(timeout=5)
        self.proc.stdout.close()
        return self.proc.returncode


SERVER = None


def setUpModule():
    global SERVER
    for var in ("HAPTICPD_SERVER", "HAPTICPD_TOKEN"):
        os.environ.pop(var, None)
    SERVER = Server()


def tearDownModule():
    if SERVER is not None:
        rc = SERVER.stop()
        if rc != 0:
            raise RuntimeError("hapticpd serve exited %s:\n%s" % (rc, "".join(SERVER.log)))


def press(top=0.05, radius=0.01, start=0.03, depth=0.015, steps=8):
    """z positions of a sphere's centre: from `start` above the top face down to
    `depth` into it, and back up (the deepest pose once)."""
    hi = top + radius + start
    lo = top + radius - depth
    down = [hi + (lo - hi) * i / steps for i in range(steps + 1)]
    return down + down[-2::-1]


class SceneTests(unittest.TestCase):
    def setUp(self):
        self.c = hapticpd.connect(SERVER.address, timeout=20)

    def tearDown(self):
        self.c.close()

    def test_connect_and_list(self):
        ids = [s.scene_id for s in self.c.list_scenes()]
        self.assertIn("default", ids)

    def test_create_get_delete_scene(self):
        cfg = {"declared": True, "effects": ["EFFECT_CONTACT"], "pdMode": "PD_MODE_PDT"}
        s = self.c.create_scene("py-create", "made from python", config=cfg)
        self.assertEqual(s.scene_id, "py-create")
        self.assertEqual(s.description, "made from python")
        by_id = {x.scene_id: x for x in self.c.list_scenes()}
        self.assertIn("py-create", by_id)
        self.assertEqual(by_id["py-create"].description, "made from python")
        got = self.c.get_scene("py-create")
        self.assertEqual(got.config.pd_mode, haptic_pb2.PD_MODE_PDT)
        self.assertEqual(list(got.config.effects), [haptic_pb2.EFFECT_CONTACT])
        with self.assertRaises(HapticpdError) as cm:
            self.c.create_scene("py-create", "again")
        self.assertEqual(cm.exception.code, "ALREADY_EXISTS")
        self.c.delete_scene("py-create")
        self.assertNotIn("py-create", [x.scene_id for x in self.c.list_scenes()])
        with self.assertRaises(HapticpdError) as cm:
            self.c.get_scene("py-create")
        self.assertEqual(cm.exception.code, "NOT_FOUND")

    def test_bodies_shape_mesh_files_move_remove(self):
        self.c.create_scene("py-bodies", "bodies")
        box = self.c.add_shape("py-bodies", "box:0.05,0.05,0.05", pose=(0.1, 0, 0),
                               body_id="box", movable=True,
                               material={"stiffness": 2000, "damping": 1.5})
        self.assertEqual(box.body_id, "box")
        self.assertTrue(box.movable)
        self.assertEqual(box.mesh_info.triangles, 12)
        # Every file format, each in 7-byte chunks (many chunk messages).
        for ext in ("obj", "off", "ply", "stl"):
            path = os.path.join(TESTDATA, "good", "tetra." + ext)
            b = self.c.add_mesh_file("py-bodies", path, body_id="tetra-" + ext,
                                     pose=hapticpd.pose(0, 0.2, 0), chunk_size=7)
            self.assertEqual(b.mesh_info.triangles, 4, ext)
            self.assertEqual(b.label, "tetra." + ext)
        # A temporary OBJ with an upper-case extension and an automatic id.
        with tempfile.TemporaryDirectory() as d:
            path = os.path.join(d, "tri_pyramid.OBJ")
            with open(path, "w") as f:
                f.write("v 0 0 0\nv 0.1 0 0\nv 0 0.1 0\nv 0 0 0.1\n"
                        "f 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n")
            auto = self.c.add_mesh_file("py-bodies", path)
        self.assertTrue(auto.body_id)
        inline = self.c.add_mesh("py-bodies", [(0, 0, 0), (1, 0, 0), (0, 1, 0), (0, 0, 1)],
                                 [(0, 2, 1), (0, 1, 3), (0, 3, 2), (1, 2, 3)],
                                 body_id="inline", pose=(0, 0, 3))
        self.assertEqual(inline.mesh_info.triangles, 4)

        scene = self.c.get_scene("py-bodies")
        ids = sorted(b.body_id for b in scene.bodies)
        self.assertEqual(ids, sorted(["box", "tetra-obj", "tetra-off", "tetra-ply",
                                      "tetra-stl", auto.body_id, "inline"]))
        got_box = [b for b in scene.bodies if b.body_id == "box"][0]
        self.assertAlmostEqual(got_box.pose.position.x, 0.1)
        self.assertAlmostEqual(got_box.material.stiffness, 2000)
        self.assertAlmostEqual(got_box.material.damping, 1.5)

        rev = self.c.move_body("py-bodies", "box", (0.2, 0.01, 0.02, 0, 0, 0, 1),
                               velocity=(0.05, 0, 0))
        self.assertGreater(rev, scene.revision)
        moved = [b for b in self.c.get_scene("py-bodies").bodies if b.body_id == "box"][0]
        self.assertAlmostEqual(moved.pose.position.x, 0.2)
        self.assertAlmostEqual(moved.pose.position.y, 0.01)
        self.assertAlmostEqual(moved.pose.orientation.z, 1)
        self.assertAlmostEqual(moved.velocity.linear.x, 0.05)

        rev2 = self.c.remove_body("py-bodies", "tetra-stl")
        self.assertGreater(rev2, rev)
        self.assertNotIn("tetra-stl", [b.body_id for b in self.c.get_scene("py-bodies").bodies])
        with_meshes = self.c.get_scene("py-bodies", include_meshes=True)
        tri = [b for b in with_meshes.bodies if b.body_id == "inline"][0]
        self.assertEqual(len(tri.mesh.triangles), 12)
        self.c.delete_scene("py-bodies")

    def test_bad_requests_raise_with_code_and_field(self):
        self.c.create_scene("py-bad", "bad input")
        self.c.add_shape("py-bad", "box", body_id="box", movable=True)
        before = self.c.get_scene("py-bad").revision
        with self.assertRaises(HapticpdError) as cm:
            self.c.move_body("py-bad", "box", (0, 0, 0, 2, 0, 0, 0))
        e = cm.exception
        self.assertEqual(e.code, "INVALID_ARGUMENT")
        self.assertEqual(e.grpc_code, grpc.StatusCode.INVALID_ARGUMENT)
        self.assertTrue(e.message.startswith("pose.orientation: quaternion norm 2"), e.message)
        self.assertTrue(str(e).startswith("INVALID_ARGUMENT: pose.orientation: "), str(e))
        self.assertEqual(self.c.get_scene("py-bad").revision, before)

        with self.assertRaises(HapticpdError) as cm:
            self.c.remove_body("py-bad", "nope")
        self.assertEqual(cm.exception.code, "NOT_FOUND")
        self.assertTrue(cm.exception.message.startswith("body_id: "), cm.exception.message)

        with self.assertRaises(HapticpdError) as cm:
            self.c.add_shape("py-bad", "box:0.1")  # a partial size list
        self.assertEqual(cm.exception.code, "INVALID_ARGUMENT")
        with self.assertRaises(HapticpdError) as cm:
            self.c.add_shape("py-bad", "box", pose=(1e6, 0, 0))
        self.assertEqual(cm.exception.code, "INVALID_ARGUMENT")
        self.assertIn("position", cm.exception.message)
        self.assertEqual(self.c.get_scene("py-bad").revision, before)

        with self.assertRaises(ValueError):
            self.c.add_mesh_file("py-bad", os.path.join(TESTDATA, "tls", "README.md"))
        with self.assertRaises(TypeError):
            self.c.move_body("py-bad", "box", (0, 0))
        self.c.delete_scene("py-bad")

    def test_couple_force_grows_pressing_into_a_box(self):
        self.c.create_scene("py-couple", "press")
        self.c.add_shape("py-couple", "box:0.05,0.05,0.05", body_id="box")
        zs = press()
        session = self.c.couple("py-couple", [(0, 0, z) for z in zs], mode="pdt",
                                probe_shape="sphere:0.01,2")
        updates = list(session)
        self.assertIsNotNone(session.welcome)
        self.assertEqual(session.welcome.mode, haptic_pb2.PD_MODE_PDT)
        # lockstep: one answer per pose, in order, echoing the pose.
        self.assertEqual(len(updates), len(zs))
        self.assertEqual([u.sequence for u in updates], list(range(1, len(zs) + 1)))
        for u, z in zip(updates, zs):
            self.assertAlmostEqual(u.pose_ref.position.z, z)
        fz = [hapticpd.vec3(u.force)[2] for u in updates]
        self.assertEqual(updates[0].status, haptic_pb2.CONTACT_STATUS_SEPARATED)
        self.assertEqual(fz[0], 0.0)
        deepest = len(zs) // 2
        self.assertEqual(updates[deepest].status, haptic_pb2.CONTACT_STATUS_PENETRATING)
        # Pressing in: the upward force grows and ends near k * depth =
        # 1000 N/m * 15 mm (the default material; the sphere is faceted).
        down = fz[:deepest + 1]
        for a, b in zip(down, down[1:]):
            self.assertGreaterEqual(b, a)
            if a > 0:
                self.assertGreater(b, a)  # strictly, once in contact
        self.assertGreater(fz[deepest], 10.0)
        self.assertLess(fz[deepest], 20.0)
        self.assertGreater(sum(1 for f in down if f > 0), 2)
        # Back up: it shrinks again to zero.
        up = fz[deepest:]
        for a, b in zip(up, up[1:]):
            self.assertLessEqual(b, a)
        self.assertEqual(fz[-1], 0.0)
        self.c.delete_scene("py-couple")

    def test_couple_streaming_and_errors(self):
        self.c.create_scene("py-couple2", "stream")
        self.c.add_shape("py-couple2", "box", body_id="box")
        # Not lockstep: all poses at once; the server answers the newest.
        n = 0
        last = None
        for u in self.c.couple("py-couple2", [(0, 0, 0.2)] * 50, lockstep=False):
            n += 1
            last = u
        self.assertGreaterEqual(n, 1)
        self.assertEqual(last.sequence, 50)
        # A bad pose ends the session with the server's INVALID_ARGUMENT.
        with self.assertRaises(HapticpdError) as cm:
            list(self.c.couple("py-couple2", [(0, 0, 0.2), (0, 0, 0.2, 0, 0, 0, 0)]))
        self.assertEqual(cm.exception.code, "INVALID_ARGUMENT")
        self.assertIn("orientation", cm.exception.message)
        # A malformed pose in the caller's iterator is raised as it was.
        with self.assertRaises(TypeError):
            list(self.c.couple("py-couple2", [(0, 0, 0.2), (1, 2)]))
        # Unknown scene: NOT_FOUND.
        with self.assertRaises(HapticpdError) as cm:
            list(self.c.couple("py-no-such-scene", [(0, 0, 1)]))
        self.assertEqual(cm.exception.code, "NOT_FOUND")
        # Stopping early cancels the stream.
        s = self.c.couple("py-couple2", iter(lambda: (0, 0, 0.2), None))
        for i, _ in enumerate(s):
            if i == 5:
                break
        s.close()
        self.assertEqual(list(s), [])
        self.c.delete_scene("py-couple2")

    def test_watch_snapshot_then_changes(self):
        self.c.create_scene("py-watch", "watched")
        self.c.add_shape("py-watch", "box", body_id="first")
        w = self.c.watch("py-watch", rate_hz=30, timeout=30)
        first = next(w)
        self.assertTrue(first.HasField("snapshot"))
        self.assertEqual([b.body_id for b in first.snapshot.bodies], ["first"])
        self.c.add_shape("py-watch", "sphere", body_id="second", pose=(0.3, 0, 0), movable=True)
        added = None
        for ev in w:
            if ev.HasField("changes"):
                added = [b.body_id for b in ev.changes.added]
                break
        self.assertEqual(added, ["second"])
        self.c.move_body("py-watch", "second", (0.4, 0, 0))
        moved = False
        for ev in w:
            if ev.HasField("poses"):
                xs = {b.body_id: b.pose.position.x for b in ev.poses.bodies}
                if abs(xs.get("second", 0) - 0.4) < 1e-9:
                    moved = True
                    break
        self.assertTrue(moved)
        self.c.remove_body("py-watch", "first")
        removed = None
        for ev in w:
            if ev.HasField("changes"):
                removed = list(ev.changes.removed)
                break
        self.assertEqual(removed, ["first"])
        w.close()
        self.assertEqual(list(w), [])
        self.c.delete_scene("py-watch")

    def test_unreachable_server_is_unavailable(self):
        with hapticpd.connect("127.0.0.1:1", timeout=5) as c:
            with self.assertRaises(HapticpdError) as cm:
                c.list_scenes()
        self.assertEqual(cm.exception.code, "UNAVAILABLE")


class TokenTests(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        cls.dir = tempfile.TemporaryDirectory()
        tokens = {"tokens": [
            {"token": "adm1n", "name": "ops", "roles": {"*": ["admin"]}},
            {"token": "look", "name": "viewer", "roles": {"*": ["observe"]}},
        ]}
        path = os.path.join(cls.dir.name, "tokens.json")
        with open(path, "w") as f:
            json.dump(tokens, f)
        cls.server = Server("--tokens", path)

    @classmethod
    def tearDownClass(cls):
        cls.server.stop()
        cls.dir.cleanup()

    def code_of(self, fn):
        with self.assertRaises(HapticpdError) as cm:
            fn()
        return cm.exception.code

    def test_token_required_and_roles(self):
        addr = self.server.address
        with hapticpd.connect(addr) as c:
            self.assertEqual(self.code_of(c.list_scenes), "UNAUTHENTICATED")
        with hapticpd.connect(addr, token="wrong") as c:
            self.assertEqual(self.code_of(c.list_scenes), "UNAUTHENTICATED")
        with hapticpd.connect(addr, token="look") as c:
            self.assertIn("default", [s.scene_id for s in c.list_scenes()])
            self.assertEqual(self.code_of(lambda: c.create_scene("py-tok", "")),
                             "PERMISSION_DENIED")
        with hapticpd.connect(addr, token="adm1n") as c:
            c.create_scene("py-tok", "by the admin")
            c.add_shape("py-tok", "box", body_id="b")
            self.assertEqual([b.body_id for b in c.get_scene("py-tok").bodies], ["b"])
            c.delete_scene("py-tok")


class TlsTests(unittest.TestCase):
    def test_tls_with_ca(self):
        tls = os.path.join(TESTDATA, "tls")
        server = Server("--tls-cert", os.path.join(tls, "server.crt"),
                        "--tls-key", os.path.join(tls, "server.key"))
        try:
            with hapticpd.connect(server.address, tls_ca=os.path.join(tls, "server.crt")) as c:
                self.assertIn("default", [s.scene_id for s in c.list_scenes()])
            with hapticpd.connect(server.address, timeout=5) as c:  # plaintext to a TLS port
                with self.assertRaises(HapticpdError) as cm:
                    c.list_scenes()
                self.assertEqual(cm.exception.code, "UNAVAILABLE")
        finally:
            server.stop()


class Recorder(scene_pb2_grpc.SceneServiceServicer):
    """A SceneService that records requests and metadata."""

    def __init__(self):
        self.calls = []

    def _record(self, name, request, context):
        self.calls.append((name, request, dict(context.invocation_metadata())))

    def CreateScene(self, request, context):
        self._record("CreateScene", request, context)
        return scene_pb2.SceneSummary(scene_id=request.scene_id)

    def DeleteScene(self, request, context):
        self._record("DeleteScene", request, context)
        return scene_pb2.DeleteSceneResponse()

    def MoveBody(self, request, context):
        self._record("MoveBody", request, context)
        return scene_pb2.MoveBodyResponse(revision=7)

    def RemoveBody(self, request, context):
        self._record("RemoveBody", request, context)
        return scene_pb2.RemoveBodyResponse(revision=8)

    def AddBody(self, request_iterator, context):
        parts = list(request_iterator)
        self._record("AddBody", parts, context)
        return scene_pb2.Body(body_id=parts[0].header.spec.body_id or "body-1")


class WireTests(unittest.TestCase):
    """What the client sends: request ids, metadata, uploads."""

    def setUp(self):
        self.rec = Recorder()
        self.server = grpc.server(futures.ThreadPoolExecutor(max_workers=2))
        scene_pb2_grpc.add_SceneServiceServicer_to_server(self.rec, self.server)
        port = self.server.add_insecure_port("127.0.0.1:0")
        self.server.start()
        self.c = hapticpd.connect("127.0.0.1:%d" % port, token="tok", timeout=10)

    def tearDown(self):
        self.c.close()
        self.server.stop(None)

    def test_every_mutation_sends_a_fresh_request_id_unless_given(self):
        self.c.create_scene("s1", "d")
        self.c.create_scene("s1", "d")
        self.c.add_shape("s1", "box")
        self.c.move_body("s1", "b", (0, 0, 0))
        self.c.remove_body("s1", "b")
        self.c.delete_scene("s1")
        ids = []
        for name, req, _ in self.rec.calls:
            rid = req[0].header.request_id if name == "AddBody" else req.request_id
            self.assertRegex(rid, r"^[A-Za-z0-9_.-]{1,64}$", name)
            ids.append(rid)
        self.assertEqual(len(ids), 6)
        self.assertEqual(len(set(ids)), 6, "a fresh id per call")
        # A caller's own id goes out unchanged (a retry reuses it).
        self.c.move_body("s1", "b", (0, 0, 0), request_id="retry-1")
        self.c.move_body("s1", "b", (0, 0, 0), request_id="retry-1")
        self.c.add_shape("s1", "box", request_id="add-1")
        self.c.remove_body("s1", "b", request_id="rm-1")
        self.c.create_scene("s2", "", request_id="mk-1")
        self.c.delete_scene("s2", request_id="del-1")
        got = [(r[0].header.request_id if n == "AddBody" else r.request_id)
               for n, r, _ in self.rec.calls[6:]]
        self.assertEqual(got, ["retry-1", "retry-1", "add-1", "rm-1", "mk-1", "del-1"])

    def test_metadata_bearer_token_and_scene(self):
        self.c.move_body("lab-1", "b", (0, 0, 0))
        self.c.add_shape("lab-1", "box")
        for name, _, md in self.rec.calls:
            self.assertEqual(md.get("authorization"), "Bearer tok", name)
            self.assertEqual(md.get("x-hapticpd-scene"), "lab-1", name)

    def test_mesh_upload_chunks_format_and_total_bytes(self):
        for ext, fmt in (("obj", types_pb2.MESH_FORMAT_OBJ), ("stl", types_pb2.MESH_FORMAT_STL),
                         ("ply", types_pb2.MESH_FORMAT_PLY), ("off", types_pb2.MESH_FORMAT_OFF)):
            path = os.path.join(TESTDATA, "good", "tetra." + ext)
            with open(path, "rb") as f:
                data = f.read()
            self.c.add_mesh_file("s", path, chunk_size=5, body_id="t", movable=True,
                                 pose=(1, 2, 3))
            parts = self.rec.calls[-1][1]
            h = parts[0].header
            self.assertEqual(h.format, fmt, ext)
            self.assertEqual(h.total_bytes, len(data), ext)
            self.assertEqual(h.spec.label, "tetra." + ext)
            self.assertEqual(h.spec.body_id, "t")
            self.assertTrue(h.spec.movable)
            self.assertEqual(h.spec.pose.position.z, 3)
            self.assertTrue(all(p.HasField("chunk") for p in parts[1:]))
            self.assertTrue(all(len(p.chunk) <= 5 for p in parts[1:]))
            self.assertEqual(b"".join(p.chunk for p in parts[1:]), data, ext)


if __name__ == "__main__":
    unittest.main()
