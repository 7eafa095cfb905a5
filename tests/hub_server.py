"""A loopback stand-in for the Hugging Face Hub's dataset endpoints, for the real huggingface_hub client.

Serves one dataset repository from a dict ``path -> bytes``: repo info, the recursive tree listing
and file downloads (``HEAD``/``GET`` with ``X-Repo-Commit`` and ``ETag``). Point ``HF_ENDPOINT`` at
``server.url`` (it is read when huggingface_hub is imported, so use it in a subprocess).
"""

from __future__ import annotations

import hashlib
import json
import threading
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from urllib.parse import unquote, urlparse


class FakeHub:
    def __init__(self, repo_id: str, files: dict[str, bytes], commit: str = "c0ffee" * 6 + "abcd") -> None:
        self.repo_id, self.files, self.commit = repo_id, files, commit
        self.requests: list[str] = []
        hub = self

        class Handler(BaseHTTPRequestHandler):
            def log_message(self, *args):  # quiet
                pass

            def _send(self, code: int, body: bytes = b"", headers: dict | None = None, head: bool = False):
                self.send_response(code)
                for k, v in (headers or {}).items():
                    self.send_header(k, v)
                self.send_header("Content-Length", str(len(body)))
                self.end_headers()
                if not head:
                    self.wfile.write(body)

            def _json(self, obj, code=200):
                self._send(code, json.dumps(obj).encode(), {"Content-Type": "application/json"})

            def _route(self, head: bool):
                path = unquote(urlparse(self.path).path)
                hub.requests.append(f"{self.command} {path}")
                api = f"/api/datasets/{hub.repo_id}"
                resolve = f"/datasets/{hub.repo_id}/resolve/"
                if path.startswith(f"{api}/revision/"):
                    rev = path[len(f"{api}/revision/") :]
                    if rev not in ("main", hub.commit):
                        return self._send(404, b'{"error":"Revision Not Found"}', {"X-Error-Code": "RevisionNotFound"})
                    return self._json({"id": hub.repo_id, "sha": hub.commit, "private": False,
                                       "siblings": [{"rfilename": p} for p in sorted(hub.files)]})  # fmt: skip
                if path.startswith(f"{api}/tree/"):
                    entries, dirs = [], set()
                    for p, data in sorted(hub.files.items()):
                        parts = p.split("/")
                        for i in range(1, len(parts)):
                            dirs.add("/".join(parts[:i]))
                        entries.append({"type": "file", "path": p, "size": len(data), "oid": hashlib.sha1(data).hexdigest()})
                    entries += [{"type": "directory", "path": d, "oid": "0" * 40, "size": 0} for d in sorted(dirs)]
                    return self._json(entries)
                if path.startswith(resolve):
                    rev, _, name = path[len(resolve) :].partition("/")
                    if name not in hub.files or rev not in ("main", hub.commit):
                        return self._send(404, b'{"error":"Entry not found"}', {"X-Error-Code": "EntryNotFound"}, head)
                    data = hub.files[name]
                    etag = '"' + hashlib.sha1(data).hexdigest() + '"'
                    return self._send(200, data, {"ETag": etag, "X-Repo-Commit": hub.commit,
                                                  "Content-Type": "application/octet-stream"}, head)  # fmt: skip
                if path.startswith("/api/datasets/"):
                    return self._send(404, b'{"error":"Repository not found"}', {"X-Error-Code": "RepoNotFound"}, head)
                return self._send(404, b"not found", head=head)

            def do_GET(self):
                self._route(head=False)

            def do_HEAD(self):
                self._route(head=True)

        self.server = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.url = f"http://127.0.0.1:{self.server.server_address[1]}"
        self.thread = threading.Thread(target=self.server.serve_forever, daemon=True)

    def __enter__(self) -> "FakeHub":
        self.thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self.server.shutdown()
        self.server.server_close()
