#!/usr/bin/python3
"""A WebSocket client that completes the upgrade and then never reads.

Usage: stalled_ws_client.py PORT PATH_AND_QUERY

Its receive buffer is made small (SO_RCVBUF 4 KiB, set before connecting,
so the advertised window stays small) so that the sender's queue fills
within a second of steady traffic. Prints "upgraded LOCAL_PORT" once the
server answered 101, then sleeps until killed. Exits 1 if the upgrade is
refused. (Node cannot set SO_RCVBUF on a TCP socket.)
"""
import base64
import os
import socket
import sys
import time

port, path = int(sys.argv[1]), sys.argv[2]
s = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
s.connect(("127.0.0.1", port))
key = base64.b64encode(os.urandom(16)).decode()
s.sendall((f"GET {path} HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nUpgrade: websocket\r\n"
           f"Connection: Upgrade\r\nSec-WebSocket-Key: {key}\r\n"
           "Sec-WebSocket-Version: 13\r\n\r\n").encode())
head = b""
while b"\r\n\r\n" not in head:
    chunk = s.recv(1)  # byte by byte: take nothing past the response head
    if not chunk:
        print("closed before the upgrade answer", flush=True)
        sys.exit(1)
    head += chunk
status = head.split(b"\r\n", 1)[0].decode("latin1")
if " 101 " not in status + " ":
    print(f"refused: {status}", flush=True)
    sys.exit(1)
print(f"upgraded {s.getsockname()[1]}", flush=True)
while True:
    time.sleep(3600)
