#!/usr/bin/env python3
"""Drives a scripted device session with the hapticpd Python client: creates a
scene, adds a 10 cm box, presses a 1 cm sphere 15 mm into its top face and
back out (one answer per pose), prints the force of every answer, and
deletes the scene.

    build/release/client/python/hapticpd-python client/python/examples/drive_session.py \
        --server 127.0.0.1:50051
or
    PYTHONPATH=build/release/client/python/gen:client/python \
        /usr/bin/python3 client/python/examples/drive_session.py --server 127.0.0.1:50051
"""
import argparse
import os
import sys

try:
    import hapticpd
except ImportError as e:
    sys.exit("drive_session.py: %s\n(run it with build/<preset>/client/python/hapticpd-python, "
             "or set PYTHONPATH=build/<preset>/client/python/gen:client/python)" % e)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--server", default=None, help="HOST:PORT ($HAPTICPD_SERVER, 127.0.0.1:50051)")
    ap.add_argument("--token", default=None, help="token ($HAPTICPD_TOKEN)")
    ap.add_argument("--tls-ca", default=None, help="CA certificate (PEM) for TLS")
    ap.add_argument("--scene", default="py-drive-%d" % os.getpid(), help="scene to create")
    ap.add_argument("--mode", default="pdt", choices=["pdt", "pdg", "none"])
    ap.add_argument("--steps", type=int, default=10, help="poses on the way down")
    ap.add_argument("--keep", action="store_true", help="keep the scene at the end")
    a = ap.parse_args()

    top, radius, depth = 0.05, 0.01, 0.015
    hi, lo = top + radius + 0.02, top + radius - depth
    down = [hi + (lo - hi) * i / a.steps for i in range(a.steps + 1)]
    script = down + down[-2::-1]

    try:
        with hapticpd.connect(a.server, token=a.token, tls_ca=a.tls_ca) as c:
            c.create_scene(a.scene, "drive_session.py: a box to press")
            try:
                box = c.add_shape(a.scene, "box:0.05,0.05,0.05", body_id="box")
                print("scene %s: body %s (%d triangles)"
                      % (a.scene, box.body_id, box.mesh_info.triangles))
                session = c.couple(a.scene, ((0.0, 0.0, z) for z in script), mode=a.mode,
                                   probe_shape="sphere:0.01,2", client_name="drive_session.py")
                print("%4s %9s %10s %9s  %s" % ("seq", "z [m]", "Fz [N]", "depth [m]", "status"))
                for u in session:
                    fx, fy, fz = hapticpd.vec3(u.force)
                    status = hapticpd.haptic_pb2.ContactStatus.Name(u.status)
                    print("%4d %9.4f %10.4f %9.5f  %s" % (u.sequence, u.pose_ref.position.z, fz,
                                                         u.depth,
                                                         status.replace("CONTACT_STATUS_", "")))
                print("session %s: %d poses, %d answers"
                      % (session.welcome.session_id if session.welcome else "?",
                         session.sent, session.received))
            finally:
                if not a.keep:
                    c.delete_scene(a.scene)
    except hapticpd.HapticpdError as e:
        sys.exit("drive_session.py: %s" % e)
    return 0


if __name__ == "__main__":
    sys.exit(main())
