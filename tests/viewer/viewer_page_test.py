#!/usr/bin/python3
"""End-to-end test of the live web viewer (services/viewer) in a headless browser.

    viewer_page_test.py BIN_DIR WORK_DIR

runs the README's main command, scripts/run.sh, on the servers built in BIN_DIR with this
script as the client. run.sh starts every service and picking-viewer, then runs

    viewer_page_test.py --client --picking BIN_DIR/picking --address HOST:PORT \
        --viewer http://127.0.0.1:PORT --task TASK.json --out OUT

which starts the task with the `picking` CLI and checks the viewer while it runs:

  1. when the first detection is in /api/view, the page (headless Chromium, driven through
     the DevTools protocol) shows the detected item where the server says it is, in the
     target highlight colour, and the shelf where the cell says it is: points are projected
     here, in Python, with the page's camera matrices, and looked up in a screenshot;
  2. the work order table has a row per item with the server's state;
  3. after the task: the page says it finished, with the state and the score the
     orchestrator reports (`picking score ID --json`).

Screenshots land in OUT/viewer/ (first_detection.png, finished.png). Only the standard
library and python3-websocket are used (Debian's /usr/bin/python3); PNGs are decoded here.
Exit status 0 on success, 1 with a message on failure.
"""

import argparse
import base64
import colorsys
import json
import os
import shutil
import signal
import struct
import subprocess
import sys
import tempfile
import time
import urllib.error
import urllib.request
import zlib

import websocket

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
TASK_FILE = os.path.join(ROOT, 'tests/data/tasks/pick_layout_1_three_items.json')

# Browser window: the page's canvas is the left part of it.
WINDOW = (1280, 800)

# Colour classes, by hue (degrees) and saturation, so that Lambert shading (which scales the
# channels, keeping hue and saturation) does not matter. The page draws the shelf in light
# wood (0xd8b47e: hue 36, saturation 0.42) and the target detection in orange (0xff7a00:
# hue 29, saturation 1.0): the hues are close, saturation tells them apart.
TARGET_HUE = (12.0, 48.0)
TARGET_MIN_SATURATION = 0.72
SHELF_HUE = (18.0, 55.0)
SHELF_SATURATION = (0.18, 0.64)
MIN_VALUE = 0.12            # darker pixels have no reliable hue
BACKGROUND = (0x1e, 0x23, 0x30)

# Work-order states in the order an attempt goes through them.
STATE_ORDER = ['waiting', 'scanning', 'detected', 'planned', 'picking', 'picked', 'failed']


class Failure(Exception):
    """A check failed; the message says what was expected and what was seen."""


def log(message):
    print('viewer test: ' + message, flush=True)


# ---------------------------------------------------------------------------------------------
# HTTP


def get_json(url, timeout=10):
    with urllib.request.urlopen(url, timeout=timeout) as response:
        return json.loads(response.read().decode('utf-8'))


def wait_for(what, fetch, accept, timeout_s, interval_s=1.0):
    """Calls fetch() until accept(value) holds; returns the value. Failure names the last
    value (or error) seen."""
    deadline = time.monotonic() + timeout_s
    last = 'nothing'
    while True:
        try:
            value = fetch()
            if accept(value):
                return value
            last = value
        except (OSError, ValueError, urllib.error.URLError) as error:
            last = 'error: %s' % error
        if time.monotonic() > deadline:
            text = last if isinstance(last, str) else json.dumps(last)[:600]
            raise Failure('timed out after %.0f s waiting for %s; last seen: %s'
                          % (timeout_s, what, text))
        time.sleep(interval_s)


# ---------------------------------------------------------------------------------------------
# PNG decoding (8-bit RGB / RGBA, non-interlaced: what Chromium's screenshots are)


class Image:
    def __init__(self, width, height, channels, pixels):
        self.width = width
        self.height = height
        self.channels = channels
        self.pixels = pixels  # bytes, row-major, `channels` bytes per pixel

    def rgb(self, x, y):
        i = (y * self.width + x) * self.channels
        return self.pixels[i], self.pixels[i + 1], self.pixels[i + 2]


def _paeth(a, b, c):
    p = a + b - c
    pa, pb, pc = abs(p - a), abs(p - b), abs(p - c)
    if pa <= pb and pa <= pc:
        return a
    return b if pb <= pc else c


def decode_png(data):
    if data[:8] != b'\x89PNG\r\n\x1a\n':
        raise Failure('screenshot is not a PNG')
    pos, idat, header = 8, [], None
    while pos < len(data):
        length, kind = struct.unpack('>I4s', data[pos:pos + 8])
        body = data[pos + 8:pos + 8 + length]
        pos += 12 + length
        if kind == b'IHDR':
            header = struct.unpack('>IIBBBBB', body)
        elif kind == b'IDAT':
            idat.append(body)
        elif kind == b'IEND':
            break
    width, height, depth, color_type, _, _, interlace = header
    if depth != 8 or color_type not in (2, 6) or interlace != 0:
        raise Failure('unsupported PNG (depth %d, colour type %d, interlace %d)'
                      % (depth, color_type, interlace))
    bpp = 3 if color_type == 2 else 4
    raw = zlib.decompress(b''.join(idat))
    stride = width * bpp
    out = bytearray(height * stride)
    previous = bytearray(stride)
    for y in range(height):
        start = y * (stride + 1)
        kind = raw[start]
        line = bytearray(raw[start + 1:start + 1 + stride])
        if kind == 1:    # Sub
            for i in range(bpp, stride):
                line[i] = (line[i] + line[i - bpp]) & 0xff
        elif kind == 2:  # Up
            for i in range(stride):
                line[i] = (line[i] + previous[i]) & 0xff
        elif kind == 3:  # Average
            for i in range(stride):
                left = line[i - bpp] if i >= bpp else 0
                line[i] = (line[i] + ((left + previous[i]) >> 1)) & 0xff
        elif kind == 4:  # Paeth
            for i in range(stride):
                left = line[i - bpp] if i >= bpp else 0
                upper_left = previous[i - bpp] if i >= bpp else 0
                line[i] = (line[i] + _paeth(left, previous[i], upper_left)) & 0xff
        elif kind != 0:
            raise Failure('bad PNG filter type %d in row %d' % (kind, y))
        out[y * stride:(y + 1) * stride] = line
        previous = line
    return Image(width, height, bpp, bytes(out))


# ---------------------------------------------------------------------------------------------
# Colours


def hsv(rgb):
    h, s, v = colorsys.rgb_to_hsv(rgb[0] / 255.0, rgb[1] / 255.0, rgb[2] / 255.0)
    return h * 360.0, s, v


def is_target_colour(rgb):
    h, s, v = hsv(rgb)
    return v >= MIN_VALUE and s >= TARGET_MIN_SATURATION and TARGET_HUE[0] <= h <= TARGET_HUE[1]


def is_shelf_colour(rgb):
    h, s, v = hsv(rgb)
    return (v >= MIN_VALUE and SHELF_SATURATION[0] <= s <= SHELF_SATURATION[1]
            and SHELF_HUE[0] <= h <= SHELF_HUE[1])


def describe(rgb):
    h, s, v = hsv(rgb)
    return '#%02x%02x%02x (hue %.0f, sat %.2f, val %.2f)' % (rgb + (h, s, v))


# ---------------------------------------------------------------------------------------------
# Geometry: 4x4 matrices as 16 numbers in column-major order (three.js / the viewer API)


def transform(m, p, w=1.0):
    """m (column-major 16) times (p, w): returns 4 numbers."""
    return [m[r] * p[0] + m[4 + r] * p[1] + m[8 + r] * p[2] + m[12 + r] * w for r in range(4)]


class Projection:
    """The page camera: base-frame points to screenshot pixels (x right, y down)."""

    def __init__(self, camera):
        self.view = camera['view']
        self.projection = camera['projection']
        self.width = camera['width']
        self.height = camera['height']
        self.left = camera.get('left', 0)
        self.top = camera.get('top', 0)
        self.scale = camera.get('devicePixelRatio', 1) or 1

    def pixel(self, point):
        eye = transform(self.view, point)
        clip = transform(self.projection, eye[:3])
        if clip[3] <= 1e-9:
            return None  # behind the camera
        nx, ny = clip[0] / clip[3], clip[1] / clip[3]
        if not (-1 <= nx <= 1 and -1 <= ny <= 1):
            return None
        x = (self.left + (nx + 1) / 2 * self.width) * self.scale
        y = (self.top + (1 - ny) / 2 * self.height) * self.scale
        return int(x), int(y)


def box_points(pose, size, shrink, steps, centre=(0.0, 0.0, 0.0)):
    """Base-frame points of a grid inside a box (size centred on `centre` in the pose's
    frame), shrunk toward the centre so that antialiased edges are not sampled."""
    points = []
    for i in range(steps):
        for j in range(steps):
            for k in range(steps):
                f = [(n / (steps - 1) - 0.5) * shrink if steps > 1 else 0 for n in (i, j, k)]
                local = [centre[a] + f[a] * size[a] for a in range(3)]
                points.append(transform(pose, local)[:3])
    return points


def bin_back_points(cell_bin):
    """Points on the back wall of a bin: at the end of its depth axis (its x axis) that is
    farther from the robot, which stands at the base origin in front of the openings."""
    pose, size = cell_bin['X'], cell_bin['size_m']
    ends = [transform(pose, [sign * size[0] / 2, 0, 0])[:3] for sign in (-1, 1)]
    sign = -1 if sum(c * c for c in ends[0]) > sum(c * c for c in ends[1]) else 1
    offsets = [(0, 0), (-0.3, -0.3), (0.3, -0.3), (-0.3, 0.3), (0.3, 0.3)]
    return [transform(pose, [sign * size[0] / 2 * 0.98, u * size[1], v * size[2]])[:3]
            for u, v in offsets]


def stl_bounds(data):
    """Axis-aligned bounds (min, max) of a binary or ASCII STL."""
    count = struct.unpack('<I', data[80:84])[0] if len(data) >= 84 else 0
    if len(data) == 84 + 50 * count:
        vertices = [struct.unpack('<3f', data[84 + 50 * i + 12 * k:84 + 50 * i + 12 * k + 12])
                    for i in range(count) for k in (1, 2, 3)]
    else:
        vertices = [tuple(float(v) for v in line.split()[1:4])
                    for line in data.decode('ascii', 'replace').splitlines()
                    if line.strip().startswith('vertex')]
    if not vertices:
        raise Failure('the shelf mesh has no triangles')
    return ([min(v[i] for v in vertices) for i in range(3)],
            [max(v[i] for v in vertices) for i in range(3)])


def shelf_outside_points(shelf_pose, bounds):
    """Points just outside the shelf mesh's bounds (beside it at its front, and above it),
    where a correctly placed shelf is not: a shelf drawn shifted covers some of them."""
    low, high = bounds
    front = high[0]  # the mesh's +x is out of the openings
    points = []
    for fraction in (0.35, 0.5, 0.65, 0.8):
        z = low[2] + fraction * (high[2] - low[2])
        points += [[front, high[1] + 0.15, z], [front, low[1] - 0.15, z]]
    for y in (-0.25, 0.0, 0.25):
        points.append([(low[0] + high[0]) / 2, y, high[2] + 0.2])
    return [transform(shelf_pose, p)[:3] for p in points]


# ---------------------------------------------------------------------------------------------
# Chromium through the DevTools protocol


class Browser:
    """Headless Chromium with one page, driven over its DevTools websocket."""

    def __init__(self, out_dir):
        self.profile = tempfile.mkdtemp(prefix='viewer-test-chromium-')
        self.log_file = open(os.path.join(out_dir, 'chromium.log'), 'wb')
        command = [shutil.which('chromium') or 'chromium', '--headless', '--no-sandbox',
                   '--use-angle=swiftshader', '--enable-unsafe-swiftshader',
                   '--remote-debugging-port=0', '--remote-allow-origins=*',
                   '--user-data-dir=' + self.profile,
                   '--window-size=%d,%d' % WINDOW, '--hide-scrollbars', 'about:blank']
        # Its own process group, so that killing it also ends its renderer and GPU processes.
        self.process = subprocess.Popen(command, stdout=self.log_file, stderr=subprocess.STDOUT,
                                        start_new_session=True)
        self.ws = None
        self.next_id = 0
        self.console = []  # console messages and exceptions of the page, for diagnostics
        port_file = os.path.join(self.profile, 'DevToolsActivePort')
        port = wait_for('Chromium\'s DevToolsActivePort', lambda: self._read_port(port_file),
                        lambda p: p is not None, 60, 0.2)
        targets = wait_for('a Chromium page target',
                           lambda: get_json('http://127.0.0.1:%d/json' % port),
                           lambda ts: any(t.get('type') == 'page' for t in ts), 30, 0.2)
        page = next(t for t in targets if t.get('type') == 'page')
        self.ws = websocket.create_connection(page['webSocketDebuggerUrl'], timeout=60,
                                              suppress_origin=True)
        self.call('Page.enable')
        self.call('Runtime.enable')
        # A fixed viewport at device pixel ratio 1: screenshot pixels = CSS pixels.
        self.call('Emulation.setDeviceMetricsOverride',
                  {'width': WINDOW[0], 'height': WINDOW[1], 'deviceScaleFactor': 1,
                   'mobile': False})

    def _read_port(self, path):
        if self.process.poll() is not None:
            raise Failure('Chromium exited with status %d (see chromium.log)'
                          % self.process.returncode)
        try:
            with open(path) as f:
                first = f.readline().strip()
            return int(first) if first else None
        except (OSError, ValueError):
            return None

    def call(self, method, params=None):
        self.next_id += 1
        message_id = self.next_id
        self.ws.send(json.dumps({'id': message_id, 'method': method, 'params': params or {}}))
        while True:
            message = json.loads(self.ws.recv())
            if message.get('id') == message_id:
                if 'error' in message:
                    raise Failure('%s: %s' % (method, message['error']))
                return message.get('result', {})
            self._event(message)

    def _event(self, message):
        method = message.get('method')
        params = message.get('params', {})
        if method == 'Runtime.consoleAPICalled':
            text = ' '.join(str(a.get('value', a.get('description', ''))) for a in params['args'])
            self.console.append('%s: %s' % (params.get('type'), text))
        elif method == 'Runtime.exceptionThrown':
            details = params.get('exceptionDetails', {})
            self.console.append('exception: %s' % details.get('exception', {}).get(
                'description', details.get('text')))

    def evaluate(self, expression):
        result = self.call('Runtime.evaluate', {'expression': expression, 'returnByValue': True,
                                                'awaitPromise': True})
        if 'exceptionDetails' in result:
            raise Failure('page script failed: %s: %s' % (
                expression[:80], result['exceptionDetails'].get('exception', {}).get(
                    'description', result['exceptionDetails'].get('text'))))
        return result['result'].get('value')

    def navigate(self, url):
        self.console = []
        self.call('Page.navigate', {'url': url})

    def screenshot(self, path):
        # Two animation frames first: the last update is on the canvas.
        self.evaluate('new Promise(r => requestAnimationFrame(() => requestAnimationFrame(r)))')
        data = base64.b64decode(self.call('Page.captureScreenshot', {'format': 'png'})['data'])
        with open(path, 'wb') as f:
            f.write(data)
        return data

    def close(self):
        try:
            if self.ws is not None:
                self.ws.close()
        except OSError:
            pass
        if self.process.poll() is None:
            try:
                os.killpg(self.process.pid, signal.SIGKILL)
            except OSError:
                pass
            self.process.wait()
        self.log_file.close()
        shutil.rmtree(self.profile, ignore_errors=True)


PAGE_STATE = '''(() => {
  const v = window.pickingViewer;
  if (!v) return null;
  return {ready: v.ready, counts: v.counts};
})()'''


def wait_page_ready(browser, min_detections, timeout_s=180):
    def fetch():
        state = browser.evaluate(PAGE_STATE)
        if state is None:
            return {'ready': False, 'note': 'no window.pickingViewer yet'}
        return state

    try:
        return wait_for('the page to be ready with >= %d detection(s) drawn' % min_detections,
                        fetch,
                        lambda s: s.get('ready') and
                        s['counts']['detectionsDrawn'] >= min_detections,
                        timeout_s, 0.5)
    except Failure as failure:
        raise Failure('%s; page console: %s' % (failure, browser.console[-10:] or 'empty'))


# ---------------------------------------------------------------------------------------------
# Checks


def target_item(view):
    """The item the page highlights: the task's current item, else the path's or the scan's
    (the same rule as the page's)."""
    for part, key in (('task', 'item'), ('path', 'item'), ('scan', 'item')):
        if view.get(part) and view[part].get(key):
            return view[part][key]
    return ''


def target_detection(view):
    """The highlighted detection: the target item's, else the first (as the page does)."""
    item = target_item(view)
    detections = view.get('detections') or []
    for d in detections:
        if d['item'] == item:
            return d
    return detections[0] if detections else None


def same_pose(a, b, tolerance=1e-6):
    return a is not None and b is not None and all(abs(x - y) <= tolerance
                                                   for x, y in zip(a['X'], b['X']))


def capture_detection(browser, viewer, path, attempts=10, wait_s=240.0):
    """Screenshot of the page while the server's target detection and the page's are the
    same before and after it: returns (png bytes, camera, the detection, the view). Between
    two detections (the task moved on: a quick refusal, the next target's scans) it waits for
    the next one, up to `wait_s`; `attempts` counts the screenshots a changing detection
    spoiled."""
    deadline = time.time() + wait_s
    spoiled = 0
    before = {}
    while spoiled < attempts and time.time() < deadline:
        before = get_json(viewer + '/api/view')
        detection = target_detection(before)
        if not detection:
            time.sleep(0.1)
            continue
        page_before = target_detection(browser.evaluate('window.pickingViewer.lastView'))
        png = browser.screenshot(path)
        camera = browser.evaluate('window.pickingViewer.cameraMatrices()')
        page_after = target_detection(browser.evaluate('window.pickingViewer.lastView'))
        after = get_json(viewer + '/api/view')
        if (same_pose(detection, page_before) and same_pose(detection, page_after)
                and same_pose(detection, target_detection(after))):
            return png, camera, detection, before
        spoiled += 1
        log('the detection changed during the screenshot (attempt %d), again' % spoiled)
        time.sleep(0.1)
    raise Failure('no stable detection of the current item (%r) to check; detections: %s'
                  % (target_item(before), [d['item'] for d in before.get('detections') or []]))


def check_not_blank(image, projection):
    """Many distinct colours and a good share of non-background pixels in the canvas."""
    x0, y0 = int(projection.left), int(projection.top)
    x1 = min(image.width, x0 + int(projection.width))
    y1 = min(image.height, y0 + int(projection.height))
    colours, drawn, total = set(), 0, 0
    for y in range(y0, y1, 4):
        for x in range(x0, x1, 4):
            rgb = image.rgb(x, y)
            total += 1
            colours.add((rgb[0] >> 3, rgb[1] >> 3, rgb[2] >> 3))
            if max(abs(c - b) for c, b in zip(rgb, BACKGROUND)) > 12:
                drawn += 1
    share = drawn / max(1, total)
    log('canvas: %d distinct colours, %.0f%% of it drawn over the background'
        % (len(colours), 100 * share))
    if len(colours) < 30 or share < 0.08:
        raise Failure('the canvas looks blank: %d distinct colours, %.1f%% not background'
                      % (len(colours), 100 * share))


def check_detection_pixels(image, projection, detection):
    """Points inside the detected item's box, projected with the page's camera, show the
    target highlight colour."""
    size = detection.get('box_m') or [0.05, 0.05, 0.05]
    centre = detection.get('box_center_m') or [0.0, 0.0, 0.0]
    pixels = set()
    for point in box_points(detection['X'], size, 0.6, 5, centre):
        p = projection.pixel(point)
        if p is not None and 0 <= p[0] < image.width and 0 <= p[1] < image.height:
            pixels.add(p)
    if len(pixels) < 5:
        raise Failure('the detection of %s projects outside the canvas (pixels %s)'
                      % (detection['item'], sorted(pixels)[:5]))
    hits = [p for p in pixels if is_target_colour(image.rgb(*p))]
    share = len(hits) / len(pixels)
    # A model given as a point cloud (PLY) covers less of its box than a solid does; a mesh
    # (STL: a box, a cylinder, a reconstructed scan) covers most of the inner part sampled.
    model = detection.get('model') or ''
    needed = 0.2 if model.endswith('.ply') else 0.5 if model else 0.6
    centre = projection.pixel(transform(detection['X'], centre)[:3])
    log('detection %s: %d of %d projected pixels in the highlight colour (%.0f%%, need %.0f%%);'
        ' centre %s is %s' % (detection['item'], len(hits), len(pixels), 100 * share,
                              100 * needed, centre,
                              describe(image.rgb(*centre)) if centre else 'off screen'))
    if share < needed:
        samples = ', '.join(describe(image.rgb(*p)) for p in sorted(pixels)[:6])
        raise Failure('the detected %s is not drawn where /api/view puts it: only %.0f%% of '
                      'its projected pixels have the highlight colour (e.g. %s)'
                      % (detection['item'], 100 * share, samples))


def check_shelf_pixels(image, projection, cell, viewer):
    """The back walls of the bins (or the boards in front of them) show the shelf colour."""
    bins = cell.get('bins') or []
    if len(bins) < 12:
        raise Failure('/api/cell has %d bins, expected 12' % len(bins))
    seen = []
    for b in bins:
        pixels = [projection.pixel(p) for p in bin_back_points(b)]
        pixels = [p for p in pixels if p and 0 <= p[0] < image.width and 0 <= p[1] < image.height]
        shelf = sum(1 for p in pixels if is_shelf_colour(image.rgb(*p)))
        seen.append((b['name'], shelf, len(pixels),
                     describe(image.rgb(*pixels[0])) if pixels else 'off screen'))
    good = [s for s in seen if s[2] and s[1] >= 2]
    log('shelf: %d of %d bins show the shelf colour at their back wall (%s)'
        % (len(good), len(seen), ', '.join('%s %d/%d' % s[:3] for s in seen)))
    # The arm, the scan and the item may hide a few bins; most must be visible.
    if len(good) < 8:
        raise Failure('the shelf is not drawn where /api/cell puts it: only %d of 12 bins show '
                      'the shelf colour at their back wall; centre pixels: %s'
                      % (len(good), '; '.join('%s %s' % (s[0], s[3]) for s in seen)))
    # The shelf is a repetitive structure (a shifted shelf still shows wood behind most
    # bins), so points just outside its bounds must not show it.
    with urllib.request.urlopen(viewer + cell['shelf']['mesh'], timeout=30) as response:
        bounds = stl_bounds(response.read())
    outside = [projection.pixel(p) for p in shelf_outside_points(cell['shelf']['X'], bounds)]
    outside = [p for p in outside if p and 0 <= p[0] < image.width and 0 <= p[1] < image.height]
    wrong = [p for p in outside if is_shelf_colour(image.rgb(*p))]
    log('shelf: %d of %d points just outside the shelf show the shelf colour'
        % (len(wrong), len(outside)))
    if len(outside) < 4 or len(wrong) > len(outside) // 4:
        raise Failure('the shelf is drawn beyond where /api/cell puts it: %d of %d points '
                      'outside its bounds show the shelf colour' % (len(wrong), len(outside)))


def check_detection_from_above(browser, viewer, detection, out_dir):
    """The default view looks along the shelf's depth, where a misplaced item can hide;
    from steeply above and to the side, it cannot. The page keeps the same detection
    meanwhile (else this view is skipped: the first one was checked)."""
    centre = transform(detection['X'], [0, 0, 0])[:3]
    eye = [centre[0] - 0.45, centre[1] - 0.35, centre[2] + 1.1]
    browser.evaluate('window.pickingViewer.setView(%s, %s)' % (json.dumps(eye), json.dumps(centre)))
    png = browser.screenshot(os.path.join(out_dir, 'first_detection_above.png'))
    camera = browser.evaluate('window.pickingViewer.cameraMatrices()')
    now = target_detection(get_json(viewer + '/api/view'))
    page = target_detection(browser.evaluate('window.pickingViewer.lastView'))
    browser.evaluate('window.pickingViewer.resetView()')
    if not (same_pose(detection, now) and same_pose(detection, page)):
        log('the detection changed before the view from above; not checked from there')
        return
    check_detection_pixels(decode_png(png), Projection(camera), detection)


PANEL_ROWS = '''Array.from(document.querySelectorAll('tr.item')).map(
    tr => [tr.dataset.item, tr.dataset.state])'''


def check_panel(browser, viewer, timeout_s=20):
    """A row per work-order item, each with the server's state. States move on while we
    look, so the page and two server reads around it must agree at some moment."""
    deadline = time.monotonic() + timeout_s
    while True:
        before = [[i['item'], i['state']] for i in get_json(viewer + '/api/view')['items']]
        rows = browser.evaluate(PANEL_ROWS)
        after = [[i['item'], i['state']] for i in get_json(viewer + '/api/view')['items']]
        if rows == before == after and rows:
            log('panel: %d work-order row(s) match the server: %s'
                % (len(rows), ', '.join('%s=%s' % tuple(r) for r in rows)))
            return
        if time.monotonic() > deadline:
            raise Failure('the work-order table does not match /api/view: page rows %s, '
                          'server items %s then %s' % (rows, before, after))
        time.sleep(0.3)


def check_finished(browser, viewer, picking, address, out_dir):
    view = get_json(viewer + '/api/view')
    task = view['task']
    state_text = browser.evaluate("document.getElementById('task-state').textContent")
    score_text = browser.evaluate("document.getElementById('score').textContent").strip()
    log('finished: #task-state %r, #score %r; /api/view: state %s, score %s'
        % (state_text, score_text, task['state'], task['score']))
    if task['state'] != 'succeeded':
        raise Failure('the task ended %s, expected succeeded (message: %s)'
                      % (task['state'], task.get('message')))
    if task['state'] not in state_text:
        raise Failure('#task-state says %r, expected it to name %r' % (state_text, task['state']))
    cli = subprocess.run([picking, '--address', address, 'score', task['task_id'], '--json'],
                         capture_output=True, text=True, timeout=60)
    if cli.returncode != 0:
        raise Failure('picking score failed (%d): %s' % (cli.returncode, cli.stderr.strip()))
    with open(os.path.join(out_dir, 'score.json'), 'w') as f:
        f.write(cli.stdout)
    cli_score = json.loads(cli.stdout.strip().splitlines()[-1])['score']
    log('picking score %s --json: %s' % (task['task_id'], cli_score))
    if not score_text.lstrip('-').isdigit() or int(score_text) != int(task['score']):
        raise Failure('#score shows %r, /api/view says %s' % (score_text, task['score']))
    if int(task['score']) != int(cli_score):
        raise Failure('/api/view says score %s, the orchestrator (picking score) %s'
                      % (task['score'], cli_score))


# ---------------------------------------------------------------------------------------------
# The two modes


def check_first_detection(browser, viewer, out_dir):
    """Steps 3-5: the page while a detection is shown."""
    cell = get_json(viewer + '/api/cell')
    browser.navigate(viewer + '/')
    state = wait_page_ready(browser, 1)
    log('page ready: %s' % json.dumps(state['counts']))
    png, camera, detection, view = capture_detection(
        browser, viewer, os.path.join(out_dir, 'first_detection.png'))
    image = decode_png(png)
    projection = Projection(camera)
    log('screenshot %dx%d, canvas %sx%s at (%s, %s)' % (image.width, image.height,
                                                         camera['width'], camera['height'],
                                                         projection.left, projection.top))
    check_not_blank(image, projection)
    check_detection_pixels(image, projection, detection)
    check_shelf_pixels(image, projection, cell, viewer)
    check_detection_from_above(browser, viewer, detection, out_dir)
    check_panel(browser, viewer)


def client(args):
    out_dir = os.path.join(args.out, 'viewer')
    os.makedirs(out_dir, exist_ok=True)
    picking_proc = None
    browser = None
    try:
        if not args.no_picking:
            # 1. Start the task; the CLI watches it to its end.
            picking_log = open(os.path.join(out_dir, 'picking.log'), 'wb')
            command = [args.picking, '--address', args.address, 'run', args.task]
            log('starting the task: %s' % ' '.join(command))
            picking_proc = subprocess.Popen(command, stdout=picking_log,
                                            stderr=subprocess.STDOUT)
        # 2. Wait for the first detection.
        view = wait_for('a detection in %s/api/view' % args.viewer,
                        lambda: get_json(args.viewer + '/api/view'),
                        lambda v: bool(v.get('detections')), args.detection_timeout)
        log('first detection: %s' % ', '.join('%s (%s %.2f)' % (d['item'], d.get('method'),
                                                                d.get('score') or 0)
                                               for d in view['detections']))
        browser = Browser(out_dir)
        check_first_detection(browser, args.viewer, out_dir)
        if args.no_picking:
            log('--no-picking: the finished task is not checked')
            return 0
        # 6. The end of the task.
        try:
            code = picking_proc.wait(timeout=args.task_timeout)
        except subprocess.TimeoutExpired:
            raise Failure('the task did not end within %d s (see %s/picking.log)'
                          % (args.task_timeout, out_dir))
        log('picking run exited with %d' % code)
        wait_for('the task to end in /api/view', lambda: get_json(args.viewer + '/api/view'),
                 lambda v: v.get('task') and v['task']['state'] != 'running', 60)
        browser.navigate(args.viewer + '/')
        wait_page_ready(browser, 0)
        browser.screenshot(os.path.join(out_dir, 'finished.png'))
        check_finished(browser, args.viewer, args.picking, args.address, out_dir)
        log('all checks passed; screenshots in %s' % out_dir)
        return 0
    except Failure as failure:
        print('viewer test FAILED: %s' % failure, file=sys.stderr, flush=True)
        if browser is not None and browser.console:
            print('page console:\n  ' + '\n  '.join(browser.console[-15:]), file=sys.stderr)
        return 1
    finally:
        if browser is not None:
            browser.close()
        if picking_proc is not None and picking_proc.poll() is None:
            picking_proc.terminate()
            try:
                picking_proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                picking_proc.kill()


def run_cell(bin_dir, work_dir, timeout_s=870):
    """The ctest entry: scripts/run.sh with this script as the client."""
    me = os.path.abspath(__file__)
    bin_dir = os.path.abspath(bin_dir)
    work_dir = os.path.abspath(work_dir)
    os.makedirs(work_dir, exist_ok=True)
    client_command = ('/usr/bin/python3 %s --client --picking %s/picking --address {address} '
                      '--viewer {viewer} --task {task} --out {out}' % (me, bin_dir))
    command = [os.path.join(ROOT, 'scripts/run.sh'), '--bin', bin_dir, '--task', TASK_FILE,
               '--detector-budget-scale', '10', '--out', os.path.join(work_dir, 'run'),
               '--client', client_command]
    log('running %s' % ' '.join(repr(c) if ' ' in c else c for c in command))
    process = subprocess.Popen(command, cwd=ROOT, start_new_session=True)
    try:
        code = process.wait(timeout=timeout_s)
    except subprocess.TimeoutExpired:
        print('viewer test FAILED: run.sh did not finish within %d s' % timeout_s,
              file=sys.stderr)
        os.killpg(process.pid, signal.SIGTERM)  # run.sh stops its services on TERM
        try:
            process.wait(timeout=20)
        except subprocess.TimeoutExpired:
            os.killpg(process.pid, signal.SIGKILL)
        return 1
    log('run.sh exited with %d (outputs in %s/run)' % (code, work_dir))
    return 0 if code == 0 else 1


def main():
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('bin_dir', nargs='?', help='the built servers (ctest mode)')
    parser.add_argument('work_dir', nargs='?', help='scratch folder (ctest mode)')
    parser.add_argument('--client', action='store_true', help='run as run.sh\'s client')
    parser.add_argument('--picking', help='the picking CLI')
    parser.add_argument('--address', help='the orchestrator, HOST:PORT')
    parser.add_argument('--viewer', help='the viewer\'s base URL')
    parser.add_argument('--task', default=TASK_FILE)
    parser.add_argument('--out', help='output folder (screenshots go to OUT/viewer)')
    parser.add_argument('--no-picking', action='store_true',
                        help='only check the page of a viewer that already shows a detection')
    parser.add_argument('--detection-timeout', type=float, default=400)
    parser.add_argument('--task-timeout', type=float, default=420)
    args = parser.parse_args()
    if args.client:
        if not args.viewer or not args.out or (not args.no_picking and
                                               not (args.picking and args.address)):
            parser.error('--client needs --viewer, --out, and --picking and --address')
        args.viewer = args.viewer.rstrip('/')
        return client(args)
    if not args.bin_dir or not args.work_dir:
        parser.error('usage: viewer_page_test.py BIN_DIR WORK_DIR')
    return run_cell(args.bin_dir, args.work_dir)


if __name__ == '__main__':
    sys.exit(main())
