"""The offline viewer's parts without a browser: analytics off in the viewer process's own
rerun configuration (the user's left alone), index.html served without the font links,
the empty examples list (test_web_viewer.py checks the page's requests in Chromium)."""
from __future__ import annotations

import json
import os
import subprocess
import sys
import urllib.request

from softsnap_model import viewer_offline


def test_analytics_are_disabled_in_a_private_rerun_configuration(tmp_path):
    users = tmp_path / 'users_config'
    env = dict(os.environ, XDG_CONFIG_HOME=str(users))
    code = ('import os; from softsnap_model import viewer_offline; '
            'print(viewer_offline.disable_analytics()); print(os.environ["XDG_CONFIG_HOME"])')
    out = subprocess.run([sys.executable, '-c', code], env=env, capture_output=True, text=True,
                         timeout=120, check=True).stdout.split()
    private, in_process = out[0], out[1]
    assert private == in_process and private != str(users)
    shown = subprocess.run([sys.executable, '-m', 'rerun_cli', 'analytics', 'config'],
                           env=dict(os.environ, XDG_CONFIG_HOME=private), capture_output=True,
                           text=True, timeout=120).stdout
    assert json.loads(shown[shown.index('{'):])['analytics_enabled'] is False, shown
    assert not users.exists()                       # the user's configuration untouched


def test_the_proxy_drops_font_links_analytics_and_release_check_and_serves_no_examples(tmp_path):
    import http.server
    import threading
    page = (b'<html><head><link rel="preconnect" href="https://fonts.googleapis.com" />\n'
            b'<link href="https://fonts.googleapis.com/css2?family=Inter" rel="stylesheet">'
            b'<title>rerun</title></head></html>')
    code = (b'\x00asm\x01https://tel.rerun.io/api/pog\x02'
            b'https://api.github.com/repos/rerun-io/rerun/releases/latest\x03')

    class Upstream(http.server.BaseHTTPRequestHandler):
        def do_GET(self):  # noqa: N802
            wasm = self.path.endswith('.wasm')
            self.send_response(200)
            self.send_header('Content-Type', 'application/wasm' if wasm else 'text/html; charset=utf-8')
            self.end_headers()
            self.wfile.write(code if wasm else page)

        def log_message(self, *args):
            pass
    upstream = http.server.ThreadingHTTPServer(('127.0.0.1', 0), Upstream)
    threading.Thread(target=upstream.serve_forever, daemon=True).start()
    proxy = http.server.ThreadingHTTPServer(('127.0.0.1', 0), viewer_offline._handler(
        f'http://127.0.0.1:{upstream.server_address[1]}'))
    threading.Thread(target=proxy.serve_forever, daemon=True).start()
    base = f'http://127.0.0.1:{proxy.server_address[1]}'
    try:
        body = urllib.request.urlopen(base + '/index.html', timeout=10).read()
        assert b'fonts.' not in body and b'<title>rerun</title>' in body
        manifest = urllib.request.urlopen(base + viewer_offline.MANIFEST_PATH, timeout=10).read()
        assert json.loads(manifest) == []
        served = urllib.request.urlopen(base + '/re_viewer_bg.wasm', timeout=10).read()
        assert len(served) == len(code) and b'rerun.io' not in served and b'github' not in served
        assert served.count(b'http://127.0.0.1:9/') == 2
    finally:
        proxy.shutdown()
        upstream.shutdown()
