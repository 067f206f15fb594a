"""`ltbake view` (stages/view) end to end: its HTTP server, then its page in a headless browser.

- The server prints its URL (http://127.0.0.1:PORT/, PORT from --port 0) as the first line
  of stdout, and listens on 127.0.0.1 only: the same port on 127.0.0.2, on [::1] and on the
  host's non-loopback IPv4 addresses does not accept connections.
- HTTP: / is the page (text/html); an NWA frame with an explicit exposure is, pixel for
  pixel (±1 level), `ltbake relight --clamp --rotate --terms --exposure` of the same bake;
  a bad rotate/terms/method/exposure and an unknown parameter get 400 naming it, an
  unknown path 404, a 100 kB query a 4xx, and the server still answers /stats and /env.png;
  show=reference is `relight` of the reference with every term, show=difference NumPy's
  |A − B| of the two relit images at 16× the exposure; /frame.exr is the last frame, linear,
  the bytes `relight -o X.exr` writes (409 before any frame and for another frame= than the
  last, 400 for any other parameter); with --sequence, t=K is frame K of `relight --sequence`
  (NWA) byte for byte, t=2&rotate=5 is relight --rotate 25, a t past the end a 400, and a
  server without --sequence refuses t.
- The page in headless Chromium (chromium-headless-shell, driven through the DevTools
  protocol over --remote-debugging-pipe): the first frame arrives (automatic exposure
  becomes the base); the method, terms and exposure controls change the next frame's query;
  dragging 80 px on the frame rotates the environment by 40 degrees and brings a new frame
  and new figures; the frame the page shows (read back through a canvas) equals `relight`
  of the same query within 1 level; after switching back to PBI the page keeps asking for
  frames on its own until the image has converged, then stops; choosing show = |A − B|
  (the server runs with --reference rows.ltm) brings difference frames and save links
  holding the frame shown (PNG) and naming it (EXR); the time slider asks for that frame of
  the sequence, play steps on, pause stops; no script errors; a
  screenshot of the page goes to $LTB_TEST_ARTIFACTS (default ./test-artifacts)/view_page.png.
  The slowest frame request the page made is printed (a note when over 2 s).
- SIGINT stops the server: exit 130, "ltbake view: stopped", the port refuses connections.

Without a headless Chromium the browser part cannot run: the HTTP checks still do, and the
script exits 77 (ctest's skip) when they pass.

usage: view_browser_test.py PATH_TO_LTBAKE
"""
import base64
import json
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
import urllib.error
import urllib.parse
import urllib.request

import numpy as np
from PIL import Image

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from ltbtest import LTBAKE, check, failures, finish, run, write  # noqa: E402
from glossy_test import SCENE as BALL_SCENE, icosphere, write_obj  # noqa: E402

REPO = os.path.abspath(os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", ".."))
Q = ["--progress", "never"]
DEADLINE = 60.0  # seconds for any one condition to come true (CI machines are slow and shared)
POLL = 0.05


class Abort(Exception):
    """A failed step after which the rest of a part means nothing: recorded, then cleanup."""


def wait_until(cond, what, timeout=DEADLINE):
    """Polls cond() every 50 ms until it returns something truthy (returned); Abort after timeout."""
    end = time.monotonic() + timeout
    while True:
        v = cond()
        if v:
            return v
        if time.monotonic() > end:
            raise Abort(f"timed out after {timeout:.0f} s waiting for {what}")
        time.sleep(POLL)


def on_alarm(signum, frame):
    raise TimeoutError("view_browser_test: the whole script took over 300 s")




# --- the server --------------------------------------------------------------------------
class Server:
    """`ltbake view ARGS`, its stdout and stderr collected by two threads."""

    def __init__(self, *args):
        self.cmd = [LTBAKE, "view", *map(str, args)]
        self.p = subprocess.Popen(self.cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
        self.out, self.err = bytearray(), bytearray()
        self.threads = [threading.Thread(target=self._drain, args=(stream, buf), daemon=True)
                        for stream, buf in ((self.p.stdout, self.out), (self.p.stderr, self.err))]
        for t in self.threads:
            t.start()

    @staticmethod
    def _drain(stream, buf):
        for chunk in iter(lambda: stream.read1(65536), b""):
            buf.extend(chunk)

    def first_line(self):
        def line():
            if b"\n" in self.out:
                return self.out.split(b"\n", 1)[0].decode(errors="replace")
            if self.p.poll() is not None:
                raise Abort(f"ltbake view exited {self.p.returncode} before printing its URL")
            return None
        return wait_until(line, "ltbake view to print its URL")

    def stderr(self):
        return self.err.decode(errors="replace")

    def wait(self, timeout=DEADLINE):
        """The exit code (None if still running after timeout), its output read to the end."""
        try:
            self.p.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            return None
        for t in self.threads:
            t.join(timeout=10)
        return self.p.returncode

    def kill(self):
        if self.p.poll() is None:
            self.p.kill()
        try:
            self.p.wait(timeout=30)
        except subprocess.TimeoutExpired:
            pass


HTTP = urllib.request.build_opener(urllib.request.ProxyHandler({}))  # 127.0.0.1 never through a proxy


def get(url, timeout=30):
    """(status, headers, body) of GET url; status None and the error as body when there is no answer."""
    try:
        with HTTP.open(url, timeout=timeout) as r:
            return r.status, r.headers, r.read()
    except urllib.error.HTTPError as e:
        return e.code, e.headers, e.read()
    except (OSError, urllib.error.URLError) as e:
        return None, {}, repr(e).encode()


def raw_request(port, data, timeout=30):
    """(status, body) of raw request bytes sent to 127.0.0.1:port; (None, error) without an answer."""
    try:
        with socket.create_connection(("127.0.0.1", port), timeout=timeout) as c:
            c.sendall(data)
            c.shutdown(socket.SHUT_WR)
            got = b""
            while chunk := c.recv(65536):
                got += chunk
    except OSError as e:
        return None, repr(e).encode()
    m = re.match(rb"HTTP/1\.1 (\d+) ", got)
    return (int(m.group(1)) if m else None), got.split(b"\r\n\r\n", 1)[-1]


def post_map(port, name, body, upload_header=True):
    """(status, body) of POST /map?name=NAME with the file's bytes, as the page sends it."""
    head = (f"POST /map?name={urllib.parse.quote(name)} HTTP/1.1\r\nHost: 127.0.0.1\r\n"
            f"Content-Length: {len(body)}\r\n" + ("X-Ltb-Upload: 1\r\n" if upload_header else "") + "\r\n")
    return raw_request(port, head.encode() + body)


def connect_result(host, port, family=socket.AF_INET):
    """'open', 'refused' or the error of a TCP connect to (host, port)."""
    s = socket.socket(family, socket.SOCK_STREAM)
    s.settimeout(10)
    try:
        s.connect((host, port))
        return "open"
    except ConnectionRefusedError:
        return "refused"
    except OSError as e:
        return repr(e)
    finally:
        s.close()


def other_ipv4_addresses():
    """This host's IPv4 addresses outside 127/8 (from `ip -4 addr`, else the resolver)."""
    found = set()
    try:
        out = subprocess.run(["ip", "-4", "-o", "addr", "show"], capture_output=True, text=True, timeout=10).stdout
        found.update(re.findall(r"\binet (\d+\.\d+\.\d+\.\d+)/", out))
    except (OSError, subprocess.TimeoutExpired):
        pass
    try:
        found.update(a[4][0] for a in socket.getaddrinfo(socket.gethostname(), None, socket.AF_INET))
    except OSError:
        pass
    return sorted(a for a in found if not a.startswith("127."))


def png_pixels(data):
    """RGB pixels (H × W × 3, int16) of PNG bytes or a PNG path."""
    import io
    img = Image.open(io.BytesIO(data) if isinstance(data, bytes) else data)
    return np.asarray(img.convert("RGB"), np.int16)


def relight_png(matrix, env, rotate, terms, exposure, out):
    """`ltbake relight` of the same query as a view frame (NWA: each frame on its own)."""
    run("relight", matrix, "--env", env, "--clamp", "--rotate", rotate, "--terms", terms, "--exposure", exposure,
        "-o", out, *Q, timeout=120)
    return png_pixels(out) if os.path.exists(out) else None


def compare(got, want, what):
    """One check: got and want (H × W × 3) agree within 1 level (8-bit PNG quantisation)."""
    if got is None or want is None or got.shape != want.shape:
        check(False, f"{what}: shapes {None if got is None else got.shape} and {None if want is None else want.shape}")
        return
    diff = np.abs(got - want)
    print(f"{what}: max difference {diff.max()} levels")
    check(diff.max() <= 1 and want.max() > 0,
          f"{what}: max difference {diff.max()} levels at {np.unravel_index(diff.argmax(), diff.shape)} "
          f"({(diff > 1).sum()} values over 1; reference max {want.max()})")


# --- the browser -------------------------------------------------------------------------
def find_chromium():
    """A headless Chromium: chromium-headless-shell (Debian), else chromium / chromium-browser."""
    for name in ("chromium-headless-shell", "chromium", "chromium-browser", "google-chrome", "headless_shell"):
        path = shutil.which(name)
        if path:
            return path
    for path in ("/usr/lib/chromium/chromium-headless-shell", "/usr/lib/chromium/headless_shell",
                 "/usr/lib/chromium/chromium"):
        if os.access(path, os.X_OK):
            return path
    return None


class Browser:
    """Headless Chromium driven through the DevTools protocol over --remote-debugging-pipe:
    JSON commands go in on the browser's fd 3, answers and events come out of its fd 4,
    each message ended by a NUL byte. Spawned with os.posix_spawn (no Python between fork
    and exec) into its own session, so that kill() takes the whole process group."""

    def __init__(self, exe, profile, log):
        cmd_r, cmd_w = os.pipe()
        res_r, res_w = os.pipe()
        # The child's ends go to fds 3 and 4; park them at >= 10 first, so that no dup2
        # onto 3 or 4 overwrites the other one.
        hi_r, hi_w = fcntl_dupfd(cmd_r), fcntl_dupfd(res_w)
        os.close(cmd_r)
        os.close(res_w)
        self.log = log
        logfd = os.open(log, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
        argv = [exe, "--headless", "--no-sandbox", "--remote-debugging-pipe", "--disable-gpu",
                "--disable-dev-shm-usage", "--no-first-run", "--no-default-browser-check", "--no-proxy-server",
                "--force-color-profile=srgb", f"--user-data-dir={profile}", "--window-size=1200,900", "about:blank"]
        try:
            self.pid = os.posix_spawn(exe, argv, os.environ, setsid=True, file_actions=[
                (os.POSIX_SPAWN_OPEN, 0, "/dev/null", os.O_RDONLY, 0),
                (os.POSIX_SPAWN_DUP2, logfd, 1),
                (os.POSIX_SPAWN_DUP2, logfd, 2),
                (os.POSIX_SPAWN_DUP2, hi_r, 3),
                (os.POSIX_SPAWN_DUP2, hi_w, 4),
            ])
        except OSError as e:
            os.close(cmd_w)
            os.close(res_r)
            raise Abort(f"cannot start {exe}: {e}")
        finally:
            for fd in (hi_r, hi_w, logfd):
                os.close(fd)
        self.cmd_w, self.res_r = cmd_w, res_r
        self.returncode = None
        self.next_id = 0
        self.answers = {}
        self.events = []
        self.cv = threading.Condition()
        self.closed = False
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self):
        buf = b""
        while True:
            try:
                chunk = os.read(self.res_r, 1 << 20)
            except OSError:
                chunk = b""
            if not chunk:  # every holder of the write end is gone: the browser has exited
                os.close(self.res_r)
                with self.cv:
                    self.closed = True
                    self.cv.notify_all()
                return
            buf += chunk
            *messages, buf = buf.split(b"\0")
            with self.cv:
                for m in messages:
                    try:
                        msg = json.loads(m)
                    except ValueError:
                        msg = {"unparsed": m[:300].decode(errors="replace")}
                    if "id" in msg:
                        self.answers[msg["id"]] = msg
                    else:
                        self.events.append(msg)
                self.cv.notify_all()

    def send(self, method, params=None, session=None, timeout=DEADLINE):
        """The result of one DevTools command; Abort on an error answer or no answer in time."""
        with self.cv:
            self.next_id += 1
            mid = self.next_id
        msg = {"id": mid, "method": method, "params": params or {}}
        if session:
            msg["sessionId"] = session
        data = json.dumps(msg).encode() + b"\0"
        if self.cmd_w is None:
            raise Abort(f"DevTools {method}: the browser was closed")
        try:
            while data:
                data = data[os.write(self.cmd_w, data):]
        except OSError as e:
            raise Abort(f"DevTools {method}: the browser's pipe is gone ({e!r}); browser log:\n{self.log_tail()}")
        end = time.monotonic() + timeout
        with self.cv:
            while mid not in self.answers:
                left = end - time.monotonic()
                if self.closed or left <= 0:
                    raise Abort(f"DevTools {method}: {'the browser closed its pipe' if self.closed else 'no answer'}"
                                f"; browser log:\n{self.log_tail()}")
                self.cv.wait(min(left, 1.0))
            answer = self.answers.pop(mid)
        if "error" in answer:
            raise Abort(f"DevTools {method} {json.dumps(params)[:300]}: {answer['error']}")
        return answer.get("result", {})

    def exited(self):
        if self.returncode is None:
            pid, status = os.waitpid(self.pid, os.WNOHANG)
            if pid:
                self.returncode = os.waitstatus_to_exitcode(status)
        return self.returncode is not None

    def close(self):
        """Browser.close, then wait for the process (it reaps its own children); SIGKILL its
        process group if it lingers. Safe to call again."""
        try:
            if not self.closed and not self.exited():
                self.send("Browser.close", timeout=10)
            wait_until(self.exited, "the browser to exit after Browser.close", timeout=20)
        except Abort:
            pass
        finally:
            self.kill()

    def kill(self):
        try:
            os.killpg(self.pid, signal.SIGKILL)  # its own session: the wrapper script and every child
        except (ProcessLookupError, PermissionError):
            pass
        if not self.exited():
            try:
                os.waitpid(self.pid, 0)
                self.returncode = -signal.SIGKILL
            except ChildProcessError:
                pass
        if self.cmd_w is not None:  # res_r is the reader thread's: it closes it at end of file
            os.close(self.cmd_w)
            self.cmd_w = None

    def log_tail(self, n=3000):
        try:
            with open(self.log, errors="replace") as f:
                return f.read()[-n:]
        except OSError:
            return "(no log)"


def fcntl_dupfd(fd):
    import fcntl
    return fcntl.fcntl(fd, fcntl.F_DUPFD_CLOEXEC, 10)


class Page:
    """One tab, attached with flatten: commands carry its sessionId."""

    def __init__(self, browser, url):
        self.b = browser
        target = browser.send("Target.createTarget", {"url": "about:blank"})["targetId"]
        self.session = browser.send("Target.attachToTarget", {"targetId": target, "flatten": True})["sessionId"]
        self.send("Runtime.enable")  # before the page loads: its script errors come as events
        self.send("Page.navigate", {"url": url})

    def send(self, method, params=None, timeout=DEADLINE):
        return self.b.send(method, params, session=self.session, timeout=timeout)

    def eval(self, expression, timeout=DEADLINE):
        r = self.send("Runtime.evaluate", {"expression": expression, "returnByValue": True, "awaitPromise": True},
                      timeout=timeout)
        if "exceptionDetails" in r:
            d = r["exceptionDetails"]
            raise Abort(f"page script failed: {d.get('exception', {}).get('description', d.get('text'))}\n"
                        f"in: {expression[:300]}")
        return r["result"].get("value")

    def state(self):
        """window.ltb and the figures the page shows, in one evaluation."""
        return self.eval("""(() => {
          const ltb = window.ltb || null;
          const t = (id) => { const e = document.getElementById(id); return e ? e.textContent : null; };
          return {ltb: ltb && {frames: ltb.frames, rotate: ltb.rotate, base: ltb.base, last: ltb.last,
                               stats: ltb.stats, error: ltb.error},
                  ms: t('ms'), used: t('used'), count: t('count'), err: t('err')};
        })()""")

    def wait_state(self, cond, what):
        """Polls state() until cond(state) holds; the last state goes into the failure message."""
        seen = {}

        def ok():
            seen["s"] = self.state()
            return seen["s"] if seen["s"]["ltb"] and cond(seen["s"]["ltb"]) else None
        try:
            return wait_until(ok, what)
        except Abort as e:
            raise Abort(f"{e}; page state: {json.dumps(seen.get('s'))[:1500]}")

    def exceptions(self):
        with self.b.cv:
            return [e["params"]["exceptionDetails"] for e in self.b.events
                    if e.get("method") == "Runtime.exceptionThrown" and e.get("sessionId") == self.session]

    def mouse(self, kind, x, y, buttons):
        self.send("Input.dispatchMouseEvent", {"type": kind, "x": x, "y": y, "button": "left", "buttons": buttons,
                                               "clickCount": 1 if kind != "mouseMoved" else 0})


# The frame the page shows, read back through a canvas of its natural size, with the query
# it answers. Read only when the page is idle; the frame count before and after tells.
READ_FRAME = """(async () => {
  const img = document.getElementById('frame'), before = ltb.frames, src = img.src;
  await img.decode();
  const c = document.createElement('canvas');
  c.width = img.naturalWidth; c.height = img.naturalHeight;
  const g = c.getContext('2d');
  g.drawImage(img, 0, 0);
  const d = g.getImageData(0, 0, c.width, c.height).data;
  let s = '';
  for (let i = 0; i < d.length; i += 8192) s += String.fromCharCode.apply(null, d.subarray(i, i + 8192));
  return {w: c.width, h: c.height, rgba: btoa(s), last: ltb.last, exposure: String(ltb.last.exposure),
          frame: ltb.stats.frame, steady: ltb.frames === before && img.src === src};
})()"""


def vertex_part(P, envdir, chromium):
    """A vertex bake seen from an eye: frames equal `relight --eye --orbit` byte for byte (PNG and
    EXR), tilt keeps the eye's distance, the reference and the difference, the default eye, the
    refusals; in the browser, a drag moves the eye and the light slider turns the map."""
    v, f = icosphere(3)
    write_obj(P("ball.obj"), v, f)
    write(P("ball.toml"), BALL_SCENE.format(mode="vertex", output='objects = ["ball"]', ks=0.6, exponent=16.0,
                                            obj=P("ball.obj")))
    for args in (["sample", P("ball.toml"), "-o", P("gl.ltm"), "--factor", 3], ["sample", P("ball.toml"), "-o",
                                                                                 P("plain.ltm")]):
        if run(*args, *Q, timeout=120).returncode != 0:
            raise Abort(f"the vertex bake failed: {args}")
    env = os.path.join(envdir, "sunset.exr")
    view = ["--eye", "0,-3,2", "--target", "0,0,1", "--size", "64x64"]
    run("relight", P("gl.ltm"), "--env", env, "--clamp", *view, "--orbit", "30:2", "--terms", 20, "--exposure", 0.5,
        "-o", P("orbit_%02d.png"), *Q, timeout=120)
    run("relight", P("gl.ltm"), "--env", env, "--clamp", *view, "--orbit", "30:2", "--terms", 20, "-o",
        P("orbit_%02d.exr"), *Q, timeout=120)
    run("relight", P("gl.ltm"), "--env", env, "--clamp", *view, "--orbit", "30:2", "--terms", "all", "--exposure",
        0.5, "-o", P("orbit_all_%02d.png"), *Q, timeout=120)
    srv = Server(P("gl.ltm"), "--env", env, "--clamp", "--port", 0, *view, "--reference", P("gl.ltm"))
    browser = None
    try:
        url = srv.first_line()
        base = url.rstrip("/")
        st, h, body = get(base + "/frame.png?orbit=30&terms=20&method=nwa&exposure=0.5")
        stats = json.loads(h.get("X-Ltb-Stats") or "{}") if st == 200 else {}
        check(st == 200 and stats.get("orbit") == 30 and stats.get("brdf_terms") == 3 and
              stats.get("terms_used") == 20 and (stats.get("width"), stats.get("height")) == (64, 64),
              f"a vertex frame at orbit 30: {st} {stats} {body[:200]!r}")
        for got, ref, what in ((body, P("orbit_01.png"), "PNG"), (get(base + "/frame.exr")[2], P("orbit_01.exr"),
                                                                     "EXR")):
            with open(ref, "rb") as fh:
                check(got == fh.read(), f"the vertex frame at orbit 30 ({what}) differs from frame 1 of relight "
                      "--eye 0,-3,2 --orbit 30:2, byte for byte")
        st, h, body = get(base + "/frame.png?orbit=30&terms=20&method=nwa&exposure=0.5&show=reference")
        if st == 200:
            with open(P("orbit_all_01.png"), "rb") as fh:
                check(body == fh.read(), "show=reference of a vertex bake differs from relight --terms all of the eye")
        stats = json.loads(h.get("X-Ltb-Stats") or "{}") if st == 200 else {}
        check(st == 200 and stats.get("rel_l2", 0) > 0, f"the vertex frame against its reference: {st} {stats}")
        # Tilt raises the eye about the target, its distance kept (sqrt(10) from 0,0,1).
        st, h, body = get(base + "/frame.png?tilt=20&terms=20&method=nwa")
        eye = np.array(json.loads(h.get("X-Ltb-Stats") or "{}").get("eye", [0, 0, 0])) if st == 200 else np.zeros(3)
        el0, el1 = np.degrees(np.arctan2(1, 3)), np.degrees(np.arctan2(eye[2] - 1, np.hypot(eye[0], eye[1])))
        check(st == 200 and abs(np.linalg.norm(eye - [0, 0, 1]) - 10 ** 0.5) < 1e-9 and abs(el1 - el0 - 20) < 1e-9,
              f"tilt=20: the eye {eye.tolist()} should be at elevation {el0 + 20:.3f} deg (is {el1:.3f}), "
              "distance sqrt(10)")
        for query, says in (("method=pbi", b"nwa"), ("orbit=abc", b"orbit"), ("tilt=1e9", b"tilt")):
            st, h, body = get(base + "/frame.png?" + query)
            check(st == 400 and says in body, f"GET /frame.png?{query} of a vertex bake: {st} {body[:200]!r}")
        if chromium:
            browser = Browser(chromium, P("profile2"), P("chromium2.log"))
            page = Page(browser, url)
            s = page.wait_state(lambda ltb: ltb["frames"] >= 1, "the vertex page's first frame")
            ui = page.eval("({method: document.getElementById('method').value, pbi: document.querySelector("
                           "'#method option[value=pbi]').disabled, light: !document.getElementById('lightrow').hidden,"
                           " hint: document.getElementById('draghint').textContent,"
                           " diff: document.querySelector('#show option[value=difference]').disabled,"
                           " all: document.getElementById('allterms').checked, first: ltb.stats.terms})")
            check(ui["method"] == "nwa" and ui["pbi"] and ui["light"] and "eye" in ui["hint"] and not ui["diff"] and
                  ui["all"] and ui["first"] == "all",
                  f"the vertex page's controls: {ui}")
            box = page.eval("(() => { const r = document.getElementById('frame').getBoundingClientRect();"
                            " return {x: r.x, y: r.y, w: r.width, h: r.height}; })()")
            x, y = int(box["x"] + box["w"] / 2), int(box["y"] + box["h"] / 2)
            page.mouse("mousePressed", x, y, 1)
            for step in range(1, 5):
                page.mouse("mouseMoved", x + 10 * step, y + 5 * step, 1)
            page.mouse("mouseReleased", x + 40, y + 20, 0)
            s = page.wait_state(lambda ltb: ltb["stats"] and abs(ltb["stats"].get("orbit", 0) + 20) < 1e-6 and
                                abs(ltb["stats"].get("tilt", 0) - 10) < 1e-6,
                                "a frame of the dragged eye (40 px right, 20 down: orbit -20, tilt 10)")
            page.eval("(() => { const e = document.getElementById('light'); e.value = '45';"
                      " e.dispatchEvent(new Event('input')); })()")
            s = page.wait_state(lambda ltb: ltb["stats"] and ltb["stats"]["rotate"] == 45 and
                                abs(ltb["stats"]["orbit"] + 20) < 1e-6, "a frame of the light turned 45 degrees")
            exc = page.exceptions()
            check(not exc, f"uncaught script errors in the vertex page: {json.dumps(exc)[:1000]}")
            shot = base64.b64decode(page.send("Page.captureScreenshot", {"format": "png"})["data"])
            art = os.environ.get("LTB_TEST_ARTIFACTS") or os.path.join(os.getcwd(), "test-artifacts")
            os.makedirs(art, exist_ok=True)
            with open(os.path.join(art, "view_vertex_page.png"), "wb") as fh:
                fh.write(shot)
            browser.close()
            browser = None
    finally:
        if browser:
            browser.close()
        srv.kill()
    # A plain vertex bake with no eye given: the target is the box's centre, the eye in front of
    # it raised 25 degrees, at the distance where the box's bounding sphere fills the view.
    plain = Server(P("plain.ltm"), "--env", env, "--clamp", "--port", 0, "--size", "48x40")
    try:
        st, h, body = get(plain.first_line().rstrip("/") + "/frame.png?terms=all")
        stats = json.loads(h.get("X-Ltb-Stats") or "{}") if st == 200 else {}
        pts = np.array(v) + [0, 0, 1]
        lo, hi = pts.min(0), pts.max(0)
        d = 0.5 * np.linalg.norm(hi - lo) / np.sin(np.radians(20))
        want = (lo + hi) / 2 + d * np.array([0, -np.cos(np.radians(25)), np.sin(np.radians(25))])
        check(st == 200 and np.abs(np.array(stats.get("eye", [0, 0, 0])) - want).max() < 1e-5 and
              png_pixels(body).shape == (40, 48, 3) and png_pixels(body).max() > 0,
              f"the plain vertex bake's default view: {st} eye {stats.get('eye')} (expected {want.tolist()})")
    finally:
        plain.kill()
    p = run("view", P("plain.ltm"), "--env", env, "--size", "64", *Q, expect=2, timeout=60)
    check("--size" in p.stderr, f"view --size 64: {p.returncode} {p.stderr[-300:]}")
    # An image bake's camera is fixed: --eye is refused before anything is served.
    p = run("view", P("final.ltm"), "--env", env, "--eye", "0,-3,2", "--size", "64x64", *Q, expect=1, timeout=60)
    check("--eye, --size are for vertex bakes" in p.stderr,
          f"view of an image bake with --eye --size: {p.returncode} {p.stderr[-300:]}")


# --- the test ----------------------------------------------------------------------------
def main():
    global server, browser
    signal.signal(signal.SIGALRM, on_alarm)
    signal.alarm(300)  # the last resort; every wait below has its own, shorter deadline
    server = browser = None
    chromium = find_chromium()
    with tempfile.TemporaryDirectory() as d:
        def P(*parts):
            return os.path.join(d, *parts)

        try:
            # A tiny image bake (samples/tiny.toml at 64×48): sample → final.ltm in about a second.
            scene = open(os.path.join(REPO, "samples", "tiny.toml")).read()
            scene = re.sub(r"(?m)^width = \d+", "width = 64", re.sub(r"(?m)^height = \d+", "height = 48", scene))
            write(P("scene.toml"), scene)
            for args in (["sample", P("scene.toml"), "-o", P("raw.ltm")],
                         ["row-transform", P("raw.ltm"), "-o", P("rows.ltm")],
                         ["transpose", P("rows.ltm"), "-o", P("cols.ltm")],
                         ["column-transform", P("cols.ltm"), "-o", P("cols4d.ltm")],
                         ["quantize", P("cols4d.ltm"), "-o", P("final.ltm")]):
                if run(*args, *Q, timeout=300).returncode != 0:
                    raise Abort(f"the bake failed at {args[0]}")
            final = P("final.ltm")
            envdir = subprocess.run(["bash", os.path.join(REPO, "scripts", "find_envmaps.sh")],
                                    capture_output=True, text=True, timeout=60).stdout.strip()
            env = os.path.join(envdir, "sunset.exr")
            if not envdir or not os.path.exists(env):
                raise Abort(f"blender-data maps not found (sunset.exr under {envdir!r}): scripts/setup.sh installs "
                            "blender-data")

            # 1. The URL, first line of stdout.
            env2 = os.path.join(envdir, "forest.exr")
            # A sequence the time slider scrubs: 4 frames turning 10° each, a fade of 3 to forest, a hold.
            seq = f"rotate:10:4,fade:{env}+{env2}:3,hold:1"
            server = Server(final, "--env", env, "--env", env2, "--clamp", "--port", 0, "--method", "pbi", "--terms", 100,
                            "--reference", P("rows.ltm"), "--sequence", seq)
            url = server.first_line()
            m = re.fullmatch(r"http://127\.0\.0\.1:(\d+)/", url)
            if not m:
                raise Abort(f"the first line of stdout is {url!r}, expected http://127.0.0.1:PORT/")
            port = int(m.group(1))
            base = url.rstrip("/")

            # 2. 127.0.0.1 only: the port is open there, closed on every other local address.
            check(connect_result("127.0.0.1", port) == "open", f"127.0.0.1:{port} does not accept connections")
            others = ["127.0.0.2"] + other_ipv4_addresses()  # 127.0.0.2: loopback, but not the bound address
            if len(others) == 1:
                print("note: this host has no non-loopback IPv4 address: only 127.0.0.2 is tried")
            for a in others:
                r = connect_result(a, port)
                check(r != "open", f"{a}:{port} accepts connections: the server should listen on 127.0.0.1 only")
                if r not in ("open", "refused"):
                    print(f"note: {a}:{port}: {r} (not refused, but not open either)")
            if socket.has_ipv6:
                check(connect_result("::1", port, socket.AF_INET6) != "open",
                      f"[::1]:{port} accepts connections: the server should listen on 127.0.0.1 only")

            # 3. HTTP.
            st, h, body = get(url)
            check(st == 200 and h.get("Content-Type", "").startswith("text/html") and b'id="frame"' in body,
                  f"GET /: {st} {h.get('Content-Type') if h else None} {body[:200]!r}")
            st, h, body = get(base + "/frame.exr")
            check(st == 409 and b"no frame yet" in body, f"GET /frame.exr before any frame: {st} {body[:200]!r}")
            st, h, body = get(base + "/frame.png?rotate=30&terms=20&method=nwa&exposure=0.5")
            check(st == 200 and h.get("Content-Type") == "image/png" and body[:8] == b"\x89PNG\r\n\x1a\n",
                  f"GET /frame.png (nwa): {st} {h.get('Content-Type') if h else None} {body[:200]!r}")
            if st == 200:
                stats = json.loads(h.get("X-Ltb-Stats") or "{}")
                check(stats.get("method") == "nwa" and stats.get("terms") == 20 and stats.get("terms_used") == 20 and
                      stats.get("exposure") == 0.5 and stats.get("rotate") == 30 and
                      (stats.get("width"), stats.get("height")) == (64, 48), f"X-Ltb-Stats of the nwa frame: {stats}")
                got = png_pixels(body)
                check(got.shape == (48, 64, 3), f"/frame.png is {got.shape[1]}x{got.shape[0]}, expected 64x48")
                compare(got, relight_png(final, env, 30, 20, 0.5, P("http_ref.png")),
                        "/frame.png?rotate=30&terms=20&method=nwa&exposure=0.5 against relight")
                # The same frame, linear: the EXR `relight -o X.exr` writes, byte for byte; only the
                # last frame is kept, and a page names it (frame=N).
                run("relight", final, "--env", env, "--clamp", "--rotate", 30, "--terms", 20, "-o", P("http_ref.exr"),
                    *Q, timeout=120)
                for query in ("", f"?frame={stats.get('frame')}"):
                    st2, h2, exr = get(base + "/frame.exr" + query)
                    check(st2 == 200 and h2.get("Content-Type") == "image/x-exr" and exr[:4] == b"\x76\x2f\x31\x01",
                          f"GET /frame.exr{query}: {st2} {h2.get('Content-Type') if h2 else None} {exr[:64]!r}")
                    if os.path.exists(P("http_ref.exr")):
                        with open(P("http_ref.exr"), "rb") as f:
                            check(exr == f.read(), f"/frame.exr{query} differs from relight -o .exr of the same frame")
                for query, code in ((f"frame={stats.get('frame', 0) + 1}", 409), ("frame=x", 400), ("rotate=3", 400)):
                    st2, _, msg = get(base + "/frame.exr?" + query)
                    check(st2 == code, f"GET /frame.exr?{query}: {st2} {msg[:200]!r}, expected {code}")
            # --sequence: t=K is frame K of `relight --sequence` (NWA: frames independent), byte for
            # byte; rotate turns it further; t past the end is a 400.
            run("relight", final, "--env", env, "--clamp", "--sequence", seq, "--method", "nwa", "--terms", 20,
                "--exposure", 0.5, "-o", P("seq_%04d.png"), *Q, timeout=120)
            for t in (2, 5):
                st, h, body = get(base + f"/frame.png?t={t}&terms=20&method=nwa&exposure=0.5")
                stats = json.loads(h.get("X-Ltb-Stats") or "{}") if st == 200 else {}
                check(st == 200 and stats.get("t") == t, f"GET /frame.png?t={t}: {st} {stats}")
                if st == 200 and os.path.exists(P(f"seq_{t:04d}.png")):
                    with open(P(f"seq_{t:04d}.png"), "rb") as f:
                        check(body == f.read(), f"/frame.png?t={t} differs from frame {t} of relight --sequence {seq}")
            st, h, body = get(base + "/frame.png?t=2&rotate=5&terms=20&method=nwa&exposure=0.5")
            if st == 200:
                compare(png_pixels(body), relight_png(final, env, 25, 20, 0.5, P("http_t2.png")),
                        "/frame.png?t=2&rotate=5 (the sequence's 20° and 5 more) against relight --rotate 25")
            st, h, body = get(base + "/frame.png?t=8")
            check(st == 400 and b"0..7" in body, f"GET /frame.png?t=8: {st} {body[:200]!r}, expected 400 naming 0..7")
            # The second --env map (map=1) is `relight --env` of that map; map=2 does not exist.
            st, h, body = get(base + "/frame.png?map=1&rotate=30&terms=20&method=nwa&exposure=0.5")
            stats = json.loads(h.get("X-Ltb-Stats") or "{}") if st == 200 else {}
            check(st == 200 and stats.get("map") == 1 and stats.get("map_name") == "forest.exr",
                  f"GET /frame.png?map=1: {st} {stats}")
            if st == 200:
                compare(png_pixels(body), relight_png(final, env2, 30, 20, 0.5, P("http_ref2.png")),
                        "/frame.png?map=1&rotate=30&terms=20&method=nwa&exposure=0.5 against relight of forest.exr")
            # A map uploaded (POST /map, as the page sends it) is map 2: `relight --env` of that file;
            # a bad upload gets a 4xx naming what is wrong and changes nothing.
            env3 = os.path.join(envdir, "night.exr")
            with open(env3, "rb") as f:
                night = f.read()
            st, body = post_map(port, "night.exr", night)
            up = json.loads(body or b"{}") if st == 200 else {}
            check(st == 200 and up.get("map") == 2 and up.get("maps") == ["sunset.exr", "forest.exr", "night.exr"],
                  f"POST /map?name=night.exr: {st} {body[:300]!r}")
            st, h, body = get(base + "/frame.png?map=2&rotate=30&terms=20&method=nwa&exposure=0.5")
            stats = json.loads(h.get("X-Ltb-Stats") or "{}") if st == 200 else {}
            check(st == 200 and stats.get("map_name") == "night.exr", f"GET /frame.png?map=2 after the upload: {st} {stats}")
            if st == 200:
                compare(png_pixels(body), relight_png(final, env3, 30, 20, 0.5, P("http_ref3.png")),
                        "/frame.png?map=2 (uploaded night.exr) against relight --env night.exr")
            st, h, body = get(base + "/frame.png?t=3&map=2&terms=20&method=nwa&exposure=0.5")
            check(st == 200, f"the sequence from the uploaded map (t=3&map=2): {st} {body[:200]!r}")
            st, h, body = get(base + "/")
            check(st == 200 and b'"night.exr"' in body, f"GET / after the upload does not list night.exr: {st}")
            for name, data, header, code, says in (
                    ("night.exr", night, False, 403, b"X-Ltb-Upload"),
                    ("../night.exr", night, True, 400, b"name="),
                    ("night.png", night, True, 400, b".exr or .hdr"),
                    ("broken.exr", night[:2000], True, 400, b"uploaded broken.exr"),
                    ("garbage.hdr", b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 99999 +X 99999\n", True, 400,
                     b"uploaded garbage.hdr"),
                    ("empty.hdr", b"", True, 400, b"empty")):
                st, body = post_map(port, name, data, header)
                check(st == code and says in body, f"POST /map?name={name} ({len(data)} bytes): {st} {body[:300]!r}, "
                      f"expected {code} saying {says!r}")
                check(b"/tmp" not in body and b"ltbake-view-" not in body,
                      f"the refusal of {name} names the server's temporary file: {body[:300]!r}")
            for request, code in ((b"POST /map?name=a.hdr HTTP/1.1\r\nX-Ltb-Upload: 1\r\n\r\n", 411),
                                  (b"POST /map?name=a.hdr HTTP/1.1\r\nTransfer-Encoding: chunked\r\n\r\n0\r\n\r\n", 411),
                                  (b"POST /map?name=a.hdr HTTP/1.1\r\nContent-Length: 999999999999\r\n\r\n", 413),
                                  (b"POST /map?name=a.hdr HTTP/1.1\r\nContent-Length: 12x\r\n\r\n", 400),
                                  (b"POST /frame.png HTTP/1.1\r\nContent-Length: 1\r\n\r\nx", 405),
                                  (b"GET /map?name=a.hdr HTTP/1.1\r\n\r\n", 405),
                                  (b"PUT /map HTTP/1.1\r\nContent-Length: 1\r\n\r\nx", 405)):
                st, body = raw_request(port, request)
                check(st == code, f"{request[:60]!r}: {st} {body[:200]!r}, expected {code}")
            st, h, body = get(base + "/frame.png?map=3")
            check(st == 400 and b"0..2" in body, f"GET /frame.png?map=3 with three maps: {st} {body[:200]!r}")
            # A/B against the reference (rows.ltm, every term): show=reference is `relight rows.ltm`
            # of the same rotation and exposure; show=difference is |A - B| of the two relit
            # images at 16x the exposure, through the sRGB curve (computed here in NumPy).
            ab = {}
            for show in ("reference", "difference"):
                st, h, body = get(base + f"/frame.png?rotate=30&terms=20&method=nwa&exposure=0.5&show={show}")
                stats = json.loads((h.get("X-Ltb-Stats") if h else None) or "{}")
                check(st == 200 and stats.get("show") == show and stats.get("difference_exposure") == 8.0 and
                      stats.get("rel_l2", 0) > 0, f"GET /frame.png?...&show={show}: {st} {stats} {body[:200]!r}")
                ab[show] = png_pixels(body) if st == 200 else None
            compare(ab["reference"], relight_png(P("rows.ltm"), env, 30, "all", 0.5, P("ref_all.png")),
                    "show=reference against relight rows.ltm --terms all")
            for m, terms, npy in ((final, 20, "a.npy"), (P("rows.ltm"), "all", "b.npy")):
                run("relight", m, "--env", env, "--clamp", "--rotate", 30, "--terms", terms, "-o", P(npy), *Q,
                    timeout=120)
            if os.path.exists(P("a.npy")) and os.path.exists(P("b.npy")):
                d8 = np.clip(np.abs(np.load(P("a.npy")).astype(np.float64) - np.load(P("b.npy"))) * 8.0, 0, 1)
                srgb = np.where(d8 <= 0.0031308, 12.92 * d8, 1.055 * d8 ** (1 / 2.4) - 0.055)
                compare(ab["difference"], np.round(255 * srgb).astype(np.int16).reshape(48, 64, 3),
                        "show=difference against NumPy's |A - B| at 8")
            for query, name in (("rotate=abc", "rotate"), ("terms=0", "terms"), ("method=xyz", "method"),
                                ("bogus=1", "bogus"), ("exposure=-1", "exposure"), ("show=both", "show"),
                                ("map=9", "map"), ("map=-1", "map")):
                st, h, body = get(base + "/frame.png?" + query)
                check(st == 400 and name.encode() in body,
                      f"GET /frame.png?{query}: {st} {body[:300]!r}, expected 400 naming {name}")
            st, h, body = get(base + "/nope")
            check(st == 404, f"GET /nope: {st} {body[:200]!r}, expected 404")
            st, h, body = get(base + "/frame.png?rotate=" + "1" * 100_000)
            check(st is not None and 400 <= st < 500, f"a 100 kB query: {st} {body[:200]!r}, expected a 4xx")
            st, h, body = get(base + "/stats")
            check(st == 200 and h.get("Content-Type") == "application/json" and
                  json.loads(body or b"{}").get("method") == "nwa",
                  f"GET /stats after the bad requests: {st} {body[:300]!r} (the server should still answer)")
            st, h, body = get(base + "/env.png")
            check(st == 200 and body[:8] == b"\x89PNG\r\n\x1a\n" and png_pixels(body).shape == (128, 256, 3),
                  f"GET /env.png: {st} {body[:100]!r}")
            check(server.p.poll() is None, f"ltbake view exited ({server.p.returncode}) during the HTTP checks")

            # 4. The page in a headless browser.
            if chromium:
                browser = Browser(chromium, P("profile"), P("chromium.log"))
                t0 = time.monotonic()
                page = Page(browser, url)

                def wait_idle(cond, what):
                    """cond(ltb) with the page idle: the server's last frame is the one the page shows
                    (nothing in flight), and the page's last query is its controls' state."""
                    def ok(ltb):
                        if not (ltb["stats"] and ltb["last"] and cond(ltb)):
                            return False
                        code, _, text = get(base + "/stats", timeout=DEADLINE)
                        return code == 200 and json.loads(text).get("frame") == ltb["stats"]["frame"]
                    return page.wait_state(ok, what + ", the page idle")

                s = page.wait_state(lambda ltb: ltb["frames"] >= 1, "the page's first frame (ltb.frames >= 1)")
                first_ms = (time.monotonic() - t0) * 1000
                page.eval("performance.setResourceTimingBufferSize(100000)")
                first = page.eval("performance.getEntriesByType('resource').map((e) => e.name)"
                                  ".filter((n) => n.includes('/frame.png'))[0]")
                check(first and "exposure=0&" in first + "&" and "method=pbi" in first and "terms=100" in first,
                      f"the first frame should ask for automatic exposure (0) with --method/--terms: {first}")
                check(s["ltb"]["base"] > 0, f"ltb.base (the first frame's automatic exposure) is {s['ltb']['base']}")

                # Method NWA, 20 terms, -1 stop through the controls (their change/input events).
                page.eval("""(() => {
                  const set = (id, v, ev) => {
                    const e = document.getElementById(id); e.value = v; e.dispatchEvent(new Event(ev)); };
                  set('method', 'nwa', 'change'); set('terms', '20', 'input'); set('exposure', '-1', 'input');
                })()""")
                s = wait_idle(lambda ltb: ltb["last"]["method"] == "nwa" and ltb["last"]["terms"] == "20" and
                              ltb["last"]["exposure"] == ltb["base"] / 2,
                              "a frame with method nwa, terms 20 and exposure base / 2")
                check(s["ltb"]["stats"]["method"] == "nwa" and s["ltb"]["stats"]["terms_used"] == 20 and
                      s["used"].startswith("20 terms"), f"the nwa frame's figures: {s}")

                # The map control lists both maps; choosing forest brings its frames, then back to sunset.
                names = page.eval("Array.from(document.getElementById('map').options).map((o) => o.textContent)")
                check(names == ["sunset.exr", "forest.exr", "night.exr"], f"the map control lists {names} (the third uploaded)")
                page.eval("(() => { const e = document.getElementById('map'); e.value = '1';"
                          " e.dispatchEvent(new Event('change')); })()")
                s = wait_idle(lambda ltb: ltb["last"]["map"] == "1" and ltb["stats"]["map"] == 1,
                              "a frame of the second map after choosing it")
                check(s["ltb"]["stats"]["map_name"] == "forest.exr", f"the second map's frame: {s['ltb']['stats']}")
                page.eval("(() => { const e = document.getElementById('map'); e.value = '0';"
                          " e.dispatchEvent(new Event('change')); })()")
                s = wait_idle(lambda ltb: ltb["last"]["map"] == "0" and ltb["stats"]["map"] == 0,
                              "a frame of the first map again")

                # "add a map…": a file chosen in the page's file input is uploaded, joins the map
                # control and is shown (the server has three maps: this is the fourth).
                node = page.send("Runtime.evaluate", {"expression": "document.getElementById('upload')"})
                page.send("DOM.setFileInputFiles", {"files": [os.path.join(envdir, "city.exr")],
                                                     "objectId": node["result"]["objectId"]})
                s = wait_idle(lambda ltb: ltb["last"]["map"] == "3" and ltb["stats"]["map"] == 3,
                              "a frame of the map chosen in the file input (city.exr, map 3)")
                up = page.eval("({upload: ltb.upload, msg: document.getElementById('uploadmsg').textContent,"
                               " names: Array.from(document.getElementById('map').options).map((o) => o.textContent)})")
                check(s["ltb"]["stats"]["map_name"] == "city.exr" and up["upload"] == {"map": 3, "name": "city.exr"} and
                      up["names"][-1] == "city.exr" and "added city.exr" in up["msg"], f"the uploaded map: {up}")
                page.eval("(() => { const e = document.getElementById('map'); e.value = '0';"
                          " e.dispatchEvent(new Event('change')); })()")
                s = wait_idle(lambda ltb: ltb["last"]["map"] == "0" and ltb["stats"]["map"] == 0,
                              "a frame of the first map after the upload")

                # Drag 80 px to the right on the frame: 40 degrees.
                box = page.eval("(() => { const r = document.getElementById('frame').getBoundingClientRect();"
                                " return {x: r.x, y: r.y, w: r.width, h: r.height}; })()")
                check(box["w"] >= 32 and box["h"] >= 24, f"#frame's box {box}")
                x, y = int(box["x"] + box["w"] / 2), int(box["y"] + box["h"] / 2)
                before = s
                page.mouse("mousePressed", x, y, 1)
                for step in range(1, 9):
                    page.mouse("mouseMoved", x + 10 * step, y, 1)
                page.mouse("mouseReleased", x + 80, y, 0)
                t_drag = time.monotonic()
                s = wait_idle(lambda ltb: ltb["frames"] > before["ltb"]["frames"] and ltb["rotate"] != 0 and
                              ltb["last"]["rotate"] == f"{ltb['rotate']:.3f}", "a frame of the dragged rotation")
                drag_ms = (time.monotonic() - t_drag) * 1000
                check(abs(s["ltb"]["rotate"] - 40) < 1 and abs(float(s["ltb"]["last"]["rotate"]) - 40) < 1,
                      f"an 80 px drag should rotate by 40 degrees: ltb.rotate {s['ltb']['rotate']}, "
                      f"last {s['ltb']['last']}")
                check(abs(s["ltb"]["stats"]["rotate"] - float(s["ltb"]["last"]["rotate"])) < 1e-9,
                      f"the frame's stats rotate {s['ltb']['stats']['rotate']} is not the query's "
                      f"{s['ltb']['last']['rotate']}")
                check(s["count"] != before["count"] and s["count"] == f"{s['ltb']['frames']} frames",
                      f"#count should change with the new frame: {before['count']!r} -> {s['count']!r}")
                check(re.fullmatch(r"\d+(\.\d+)? ms", s["ms"] or "") is not None,
                      f"#ms shows {s['ms']!r}, expected '<number> ms'")
                check(s["ltb"]["last"]["method"] == "nwa" and s["ltb"]["last"]["terms"] == "20",
                      f"the drag changed method/terms: {s['ltb']['last']}")

                # The frame the page shows (idle: nwa asks for nothing more while the lighting
                # holds), read back through a canvas, against relight of its query.
                shown = page.eval(READ_FRAME)
                check(shown["steady"] and shown["frame"] == s["ltb"]["stats"]["frame"],
                      f"a new frame arrived while the page was idle: {shown['frame']} after {s['ltb']['stats']}")
                rgba = np.frombuffer(base64.b64decode(shown["rgba"]), np.uint8).reshape(shown["h"], shown["w"], 4)
                check((rgba[..., 3] == 255).all(), "the frame read back has transparent pixels")
                last = shown["last"]
                compare(rgba[..., :3].astype(np.int16),
                        relight_png(final, env, last["rotate"], last["terms"], shown["exposure"], P("page_ref.png")),
                        f"the page's frame (rotate {last['rotate']}, terms {last['terms']}, exposure {shown['exposure']})"
                        " against relight")

                # PBI again: the page keeps asking for frames with no input until the image
                # converges (a frame that touches no column), then stops.
                f0 = s["ltb"]["frames"]
                page.eval("(() => { const e = document.getElementById('method'); e.value = 'pbi';"
                          " e.dispatchEvent(new Event('change')); })()")
                s = page.wait_state(lambda ltb: ltb["frames"] >= f0 + 2 and ltb["last"]["method"] == "pbi",
                                    "two PBI frames or more after one change event")
                s = wait_idle(lambda ltb: ltb["stats"]["method"] == "pbi" and ltb["stats"]["columns_touched"] == 0,
                              "the PBI frames to converge (columns_touched 0)")
                check(s["ltb"]["last"]["rotate"] == f"{s['ltb']['rotate']:.3f}" and s["ltb"]["last"]["terms"] == "20",
                      f"PBI frames at another rotation or terms: {s['ltb']}")
                # With --reference the figures hold the frame's error against it ("error 0.60%"),
                # nothing else.
                check(s["ltb"]["error"] is None and re.fullmatch(r"error \d+\.\d\d%", s["err"] or "") is not None,
                      f"the page shows an error: {s['ltb']['error']!r} {s['err']!r}")
                exc = page.exceptions()
                check(not exc, f"uncaught script errors in the page: {json.dumps(exc)[:1000]}")
                # A/B: "show" asks for the difference image, the page says at what exposure, and the
                # save link holds the frame shown under a name that says what it is.
                page.eval("(() => { const e = document.getElementById('show'); e.value = 'difference';"
                          " e.dispatchEvent(new Event('change')); })()")
                s = wait_idle(lambda ltb: ltb["last"]["show"] == "difference" and ltb["stats"]["show"] == "difference",
                              "a difference frame after choosing show = |A - B|")
                save = page.eval("(() => { const a = document.getElementById('save'); return {href: a.href,"
                                 " name: a.download, img: document.getElementById('frame').src,"
                                 " hint: document.getElementById('showhint').textContent}; })()")
                check(save["href"] == save["img"] and save["href"].startswith("blob:") and
                      save["name"].startswith("ltbake-sunset-difference-pbi-20-rot") and "the frame's exposure" in save["hint"],
                      f"the save link and hint of a difference frame: {save}")
                # The time slider: moving it asks for that frame of the sequence; play steps on
                # by itself, pause stops it.
                page.eval("(() => { const e = document.getElementById('time'); e.value = '5';"
                          " e.dispatchEvent(new Event('input')); })()")
                wait_idle(lambda ltb: ltb["stats"].get("t") == 5 and ltb["last"].get("t") == "5",
                          "a frame of the sequence after moving the time slider to 5")
                page.eval("document.getElementById('play').click()")
                page.wait_state(lambda ltb: ltb["stats"].get("t") not in (None, 5),
                                "the sequence playing on from frame 5")
                page.eval("document.getElementById('play').click()")
                check(page.eval("document.getElementById('play').textContent") == "play",
                      "the play button did not turn back into play after pause")
                wait_idle(lambda ltb: ltb["stats"]["columns_touched"] == 0,
                          "the paused frame converged (no terms left to apply)")
                # The linear save link names the frame shown, and the server answers it with an EXR.
                exr = page.eval("(() => { const a = document.getElementById('saveexr'); return {href: a.href,"
                                " name: a.download, frame: ltb.stats.frame}; })()")
                check(exr["href"].endswith(f"/frame.exr?frame={exr['frame']}") and exr["name"] == save["name"][:-4] + ".exr",
                      f"the EXR save link of the difference frame: {exr}")
                st, h, body = get(exr["href"])
                check(st == 200 and body[:4] == b"\x76\x2f\x31\x01", f"GET {exr['href']}: {st} {body[:100]!r}")
                times = page.eval("performance.getEntriesByType('resource').filter((e) => e.name.includes('/frame.png'))"
                                  ".map((e) => e.duration)")
                slowest = max(times) if times else 0

                # A screenshot of the page, kept for people, once the lighting strip shows the last frame.
                wait_until(lambda: page.eval("(() => { const e = document.getElementById('env'); return e.complete &&"
                                             " e.naturalWidth > 0 && e.src.endsWith('f=' + ltb.stats.frame); })()"),
                           "the lighting strip (#env) of the last frame")
                shot = base64.b64decode(page.send("Page.captureScreenshot", {"format": "png"})["data"])
                art = os.environ.get("LTB_TEST_ARTIFACTS") or os.path.join(os.getcwd(), "test-artifacts")
                os.makedirs(art, exist_ok=True)
                shot_path = os.path.join(art, "view_page.png")
                with open(shot_path, "wb") as f:
                    f.write(shot)
                print(f"screenshot: {shot_path}")
                img = png_pixels(shot)
                rgb = img.astype(np.int32)
                colours = len(np.unique((rgb[..., 0] << 16) | (rgb[..., 1] << 8) | rgb[..., 2]))
                check(img.shape[0] >= 300 and img.shape[1] >= 400 and colours > 16,
                      f"the screenshot {shot_path} is {img.shape[1]}x{img.shape[0]} with {colours} colours")
                print(f"browser: first frame {first_ms:.0f} ms after the tab was opened, the dragged rotation's frame "
                      f"{drag_ms:.0f} ms after the release; {s['ltb']['frames']} frames, the slowest request "
                      f"{slowest:.0f} ms")
                if slowest > 2000:
                    print(f"note: a /frame.png request of the page took {slowest:.0f} ms: queued behind the browser's "
                          "idle keep-alive connections, which hold the server's 2 worker threads for up to 5 s?")
                browser.close()
                check(browser.returncode is not None, "the browser did not exit after Browser.close")

            # 4b. Without --reference there is nothing to compare with: show=reference is a 400
            # that says what to start the server with, and the page offers A alone.
            plain = Server(final, "--env", env, "--clamp", "--port", 0)
            try:
                purl = plain.first_line()
                st, h, body = get(purl.rstrip("/") + "/frame.png?show=reference")
                check(st == 400 and b"--reference" in body, f"show=reference without --reference: {st} {body[:300]!r}")
                st, h, body = get(purl)
                check(st == 200 and b'"reference":false' in body and b'"sequence_frames":0' in body,
                      f"the page of a server without --reference and --sequence: {st}")
                st, h, body = get(purl.rstrip("/") + "/frame.png?t=0")
                check(st == 400 and b"--sequence" in body, f"t=0 without --sequence: {st} {body[:300]!r}")
            finally:
                plain.kill()

            # 4c. A vertex bake from a moving eye: a factored (glossy, K = 3) ball and a plain one.
            vertex_part(P, envdir, chromium)

            # 5. SIGINT stops the server.
            server.p.send_signal(signal.SIGINT)
            rc = server.wait()
            check(rc == 130, f"ltbake view after SIGINT: exit {rc}, expected 130")
            check("ltbake view: stopped" in server.stderr(), f"stderr after SIGINT: {server.stderr()!r}")
            r = connect_result("127.0.0.1", port)
            check(r == "refused", f"127.0.0.1:{port} after the server stopped: {r}, expected refused")
        except (Abort, TimeoutError, subprocess.TimeoutExpired) as e:
            check(False, str(e))
        finally:
            signal.alarm(0)
            if browser:
                browser.close()
            if server:
                server.kill()
        if failures and server:
            print(f"--- {' '.join(server.cmd)}: stdout ---\n{server.out.decode(errors='replace')}"
                  f"--- stderr ---\n{server.stderr()}---")
        if failures and browser:
            print(f"--- browser log (tail) ---\n{browser.log_tail()}\n---")

    if not chromium and not failures:
        print("SKIP: no headless Chromium (chromium-headless-shell, chromium or chromium-browser): the HTTP checks "
              "passed, the page was not tried; install it with: sudo apt-get install chromium-headless-shell")
        sys.exit(77)
    finish()


if __name__ == "__main__":
    main()
