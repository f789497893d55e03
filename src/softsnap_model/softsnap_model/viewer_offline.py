"""rerun's web viewer with no network traffic beyond this machine (the `view` default).

Left to its defaults, the viewer reaches for the internet every time it starts: the SDK
process sends analytics; the page loads web fonts from a font service and the examples
list (``examples_manifest.json``) from rerun's site, sends its own analytics and asks
GitHub for rerun's latest release. Offline (our default):

- analytics: the viewer process gets a private rerun configuration directory
  (``XDG_CONFIG_HOME``) in which ``rerun analytics disable`` was run, so nothing is sent
  and the user's own rerun configuration is left as it is;
- the page: it is served through a small proxy in this process that drops the font
  links from ``index.html`` (the viewer falls back to its bundled fonts), serves an
  empty examples list, which the page is pointed at with ``manifest_url``, and in the
  viewer's WebAssembly replaces its analytics endpoint and its release check (the page
  asked ``tel.rerun.io`` and ``api.github.com`` otherwise) by a refused loopback address.

``python -m softsnap_model.recording view FILE --online`` keeps rerun's defaults.
``test/softsnap_model/test_web_viewer.py`` records every request the page makes in Chromium.
"""
from __future__ import annotations

import os
import re
import socket
import subprocess
import sys
import tempfile
import threading
import urllib.error
import urllib.request
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from urllib.parse import quote

#: Where the proxy serves the empty examples list.
MANIFEST_PATH = '/softsnap-offline/examples_manifest.json'
#: <link> elements of index.html that load fonts from the internet.
_FONT_LINK = re.compile(rb'<link[^>]*fonts\.(?:googleapis|gstatic)\.com[^>]*>\s*', re.I)
#: Addresses compiled into the viewer's WebAssembly: its analytics endpoint and its
#: release check. Each is replaced by a loopback address of the same length (the bytes
#: are string data of fixed length), on the discard port, where the request is refused
#: at once without leaving the machine.
WASM_ADDRESSES = {b'https://tel.rerun.io': b'http://127.0.0.1:9/x',
                  b'https://api.github.com': b'http://127.0.0.1:9/xxx'}
assert all(len(a) == len(b) for a, b in WASM_ADDRESSES.items())


def disable_analytics() -> str:
    """Point this process's rerun configuration at a fresh directory with analytics off;
    returns that directory (it lives as long as the process)."""
    config = tempfile.mkdtemp(prefix='softsnap-rerun-config-')
    env = dict(os.environ, XDG_CONFIG_HOME=config)
    subprocess.run([sys.executable, '-m', 'rerun_cli', 'analytics', 'disable'], env=env,
                   stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, timeout=60, check=True)
    os.environ['XDG_CONFIG_HOME'] = config   # read by rerun's native code when it starts
    return config


def free_port(host: str = '127.0.0.1') -> int:
    with socket.socket() as s:
        s.bind((host, 0))
        return s.getsockname()[1]


def _handler(upstream: str):
    class Handler(BaseHTTPRequestHandler):
        def do_GET(self):  # noqa: N802 (http.server's name)
            if self.path.split('?')[0] == MANIFEST_PATH:
                self._reply(200, 'application/json', b'[]')
                return
            try:
                with urllib.request.urlopen(upstream + self.path, timeout=30) as reply:
                    body, status = reply.read(), reply.status
                    kind = reply.headers.get('Content-Type', 'application/octet-stream')
            except urllib.error.HTTPError as error:
                body, status, kind = error.read(), error.code, 'text/plain'
            except OSError as error:
                self._reply(502, 'text/plain', f'rerun web viewer unreachable: {error}'.encode())
                return
            if kind.startswith('text/html'):
                body = _FONT_LINK.sub(b'', body)
            elif kind.startswith('application/wasm') or self.path.split('?')[0].endswith('.wasm'):
                for address, local in WASM_ADDRESSES.items():
                    body = body.replace(address, local)
            self._reply(status, kind, body)

        def _reply(self, status: int, kind: str, body: bytes) -> None:
            self.send_response(status)
            self.send_header('Content-Type', kind)
            self.send_header('Content-Length', str(len(body)))
            self.end_headers()
            self.wfile.write(body)

        def log_message(self, *args):   # quiet: the viewer fetches dozens of files
            pass
    return Handler


def serve_offline(web_port: int, grpc_url: str, host: str = '127.0.0.1') -> str:
    """Serve rerun's web viewer on `web_port` through the offline proxy; returns the page's
    url (connected to `grpc_url`). The viewer itself listens on a free loopback port."""
    import rerun as rr
    inner = free_port()
    rr.serve_web_viewer(web_port=inner, open_browser=False, connect_to=grpc_url)
    server = ThreadingHTTPServer((host, int(web_port)), _handler(f'http://127.0.0.1:{inner}'))
    threading.Thread(target=server.serve_forever, name='viewer_proxy', daemon=True).start()
    manifest = f'http://{host}:{int(web_port)}{MANIFEST_PATH}'
    return (f'http://{host}:{int(web_port)}/?url={quote(grpc_url, safe="")}'
            f'&manifest_url={quote(manifest, safe="")}')
