// Live 3D view of the picking cell, served by picking-viewer.
//
// Loads the cell (/api/cell: shelf, tote, table, bins, arm link meshes), a snapshot of the
// task (/api/view), then follows /api/stream (server-sent events, one event per part of the
// snapshot). Everything is drawn in the robot's base frame: metres, z up. Poses arrive as
// 4x4 matrices, 16 numbers in column-major order (THREE.Matrix4.fromArray order).
//
// URL parameters: ?task=ID follows that task (else the server picks the newest one);
// ?item=NAME frames that item's bin and highlights its row and detection.
//
// For tests, window.pickingViewer exposes whether the scene is ready, what was drawn, the
// camera's matrices and the last snapshot (see the object at the end of this file).
(function () {
  'use strict';

  const params = new URLSearchParams(window.location.search);
  const TASK_ID = params.get('task') || '';
  const FOCUS_ITEM = params.get('item') || '';
  const taskQuery = TASK_ID ? '?task=' + encodeURIComponent(TASK_ID) : '';

  const COLORS = {
    background: 0x1e2330,
    shelf: 0xd8b47e,       // light wood
    tote: 0x3f78c4,
    table: 0x9aa1ad,
    pedestal: 0x555c68,
    arm: 0xa7aeb8,
    gripper: 0x6c7480,
    target: 0xff7a00,      // the detection of the current / selected item
    targetEdge: 0xffd9a8,
    other: 0x6fdc4c,       // every other detection
    scan: 0x3fd7ff,
    path: 0xff3df2,
    binEdge: 0x7d8799,
    grid: 0x343b4b,
  };
  const STATES = ['waiting', 'scanning', 'detected', 'planned', 'picking', 'picked', 'failed'];

  // ---------------------------------------------------------------------------------------
  // Scene

  const canvas = document.getElementById('scene');
  const renderer = new THREE.WebGLRenderer({
    canvas: canvas,
    antialias: true,
    preserveDrawingBuffer: true,  // so that a screenshot shows the last frame
  });
  renderer.setPixelRatio(window.devicePixelRatio || 1);
  renderer.setClearColor(COLORS.background, 1);

  const scene = new THREE.Scene();
  scene.background = new THREE.Color(COLORS.background);

  const camera = new THREE.PerspectiveCamera(50, 1, 0.02, 60);
  camera.up.set(0, 0, 1);
  camera.position.set(-1.8, -0.6, 1.4);

  const controls = new THREE.OrbitControls(camera, canvas);
  controls.target.set(1.0, 0, 0.5);
  controls.enableDamping = false;  // a still camera between events: matrices match the pixels
  controls.screenSpacePanning = true;
  controls.addEventListener('change', requestRender);

  // Lights: ambient plus a key light from behind the robot (it lights the bins' insides)
  // and a weak fill from the other side. Their sum stays near 1 so colours do not clip.
  scene.add(new THREE.AmbientLight(0xffffff, 0.42));
  const key = new THREE.DirectionalLight(0xffffff, 0.55);
  key.position.set(-3, -1.5, 4);
  scene.add(key);
  const fill = new THREE.DirectionalLight(0xffffff, 0.18);
  fill.position.set(2, 3, 1);
  scene.add(fill);

  const cellGroup = new THREE.Group();     // shelf, tote, table, bins: static
  const armGroup = new THREE.Group();      // link meshes + gripper
  const scanGroup = new THREE.Group();
  const detectionGroup = new THREE.Group();
  const pathGroup = new THREE.Group();
  scene.add(cellGroup, armGroup, scanGroup, detectionGroup, pathGroup);

  function lambert(color, extra) {
    return new THREE.MeshLambertMaterial(Object.assign({color: color}, extra || {}));
  }

  function matrixFrom(array16) {
    return new THREE.Matrix4().fromArray(array16);
  }

  // Places `object` by a base-frame pose (no automatic matrix from position/rotation).
  function place(object, array16) {
    object.matrixAutoUpdate = false;
    object.matrix.copy(matrixFrom(array16));
    object.matrixWorldNeedsUpdate = true;
  }

  function setPositions(geometry, array) {
    const attribute = new THREE.BufferAttribute(array, 3);
    if (geometry.setAttribute) geometry.setAttribute('position', attribute);
    else geometry.addAttribute('position', attribute);
  }

  // ---------------------------------------------------------------------------------------
  // Rendering on demand: every change asks for one frame.

  let frameRequested = false;
  let framesRendered = 0;
  let meshesPending = 0;    // cell + link meshes still loading
  let cellLoaded = false;
  let viewLoaded = false;
  let ready = false;

  function requestRender() {
    if (frameRequested) return;
    frameRequested = true;
    window.requestAnimationFrame(renderFrame);
  }

  function resize() {
    const w = Math.max(1, canvas.clientWidth);
    const h = Math.max(1, canvas.clientHeight);
    const size = renderer.getSize(new THREE.Vector2());
    if (size.x !== w || size.y !== h) {
      renderer.setSize(w, h, false);
      camera.aspect = w / h;
      camera.updateProjectionMatrix();
    }
  }

  function renderFrame() {
    frameRequested = false;
    resize();
    renderer.render(scene, camera);
    framesRendered++;
    updateLabels();
    if (!ready && cellLoaded && viewLoaded && meshesPending === 0) ready = true;
  }

  window.addEventListener('resize', requestRender);

  // ---------------------------------------------------------------------------------------
  // The cell

  const stlLoader = new THREE.STLLoader();
  const plyLoader = new THREE.PLYLoader();
  let cell = null;
  let defaultView = null;     // {position, target}
  const linkMeshes = [];      // one per arm.links entry of the cell
  const binLabels = [];       // {element, anchor (Vector3), name}

  function loadStl(url, material, onMesh) {
    meshesPending++;
    stlLoader.load(url, function (geometry) {
      if (!geometry.attributes.normal) geometry.computeVertexNormals();
      onMesh(new THREE.Mesh(geometry, material));
      meshesPending--;
      requestRender();
    }, undefined, function (error) {
      console.error('cannot load ' + url, error);
      meshesPending--;
      requestRender();
    });
  }

  // A box whose top face is centred at the pose (tables: the pose is the top surface).
  function boxBelow(pose, size, material) {
    const geometry = new THREE.BoxBufferGeometry(size[0], size[1], size[2]);
    geometry.translate(0, 0, -size[2] / 2);
    const mesh = new THREE.Mesh(geometry, material);
    place(mesh, pose);
    return mesh;
  }

  function buildCell(c) {
    cell = c;
    // Shelf: mesh in its own frame, placed by X.
    const shelfMaterial = lambert(COLORS.shelf, {side: THREE.DoubleSide});
    if (c.shelf && c.shelf.mesh) {
      loadStl(c.shelf.mesh, shelfMaterial, function (mesh) {
        place(mesh, c.shelf.X);
        mesh.name = 'shelf';
        cellGroup.add(mesh);
      });
    }
    // Tote: mesh, or a box of its inner size standing on its pose.
    if (c.tote) {
      const toteMaterial = lambert(COLORS.tote, {side: THREE.DoubleSide});
      if (c.tote.mesh) {
        loadStl(c.tote.mesh, toteMaterial, function (mesh) {
          place(mesh, c.tote.X);
          mesh.name = 'tote';
          cellGroup.add(mesh);
        });
      } else if (c.tote.inner_size_m) {
        const s = c.tote.inner_size_m;
        const geometry = new THREE.BoxBufferGeometry(s[0], s[1], s[2]);
        geometry.translate(0, 0, s[2] / 2);
        const mesh = new THREE.Mesh(geometry, toteMaterial);
        place(mesh, c.tote.X);
        cellGroup.add(mesh);
      }
    }
    // Table: the pose is the centre of the top surface; the box hangs below it.
    if (c.table && c.table.size_m) {
      cellGroup.add(boxBelow(c.table.X, c.table.size_m, lambert(COLORS.table)));
    }
    // Floor and pedestal: the shelf stands on the floor (its mesh frame's z = 0).
    const floorZ = c.shelf && c.shelf.X ? c.shelf.X[14] : -0.7;
    if (floorZ < -0.05) {
      const pedestal = new THREE.Mesh(
          new THREE.CylinderBufferGeometry(0.09, 0.11, -floorZ, 24), lambert(COLORS.pedestal));
      pedestal.rotation.x = Math.PI / 2;
      pedestal.position.set(0, 0, floorZ / 2);
      cellGroup.add(pedestal);
    }
    const grid = new THREE.GridHelper(6, 24, COLORS.grid, COLORS.grid);
    grid.rotation.x = Math.PI / 2;  // GridHelper lies in x-z; the floor is x-y here
    grid.position.set(0.5, 0, floorZ + 0.001);
    cellGroup.add(grid);

    // Bins: a thin outline each (orange for the selected / current item's bin) and their
    // letter at the opening.
    (c.bins || []).forEach(function (bin) {
      const box = new THREE.BoxBufferGeometry(bin.size_m[0], bin.size_m[1], bin.size_m[2]);
      const edges = new THREE.LineSegments(new THREE.EdgesGeometry(box),
          new THREE.LineBasicMaterial({color: COLORS.binEdge, transparent: true, opacity: 0.35}));
      place(edges, bin.X);
      edges.name = bin.name;
      cellGroup.add(edges);
      const g = binGeometry(bin);
      const element = document.createElement('div');
      element.className = 'bin-label';
      element.textContent = bin.name.replace(/^bin_/, '');
      labelsElement.appendChild(element);
      // Top corner of the opening on the bin's +y side.
      const anchor = g.centre.clone().addScaledVector(g.open, g.size[0] / 2)
          .addScaledVector(g.side, g.size[1] / 2 - 0.02)
          .addScaledVector(g.vertical, g.size[2] / 2 - 0.03);
      binLabels.push({element: element, anchor: anchor, name: bin.name, edges: edges});
    });
    updateBinFocus();

    // Arm links: loaded once, placed by every arm update.
    const armMaterial = lambert(COLORS.arm);
    ((c.arm && c.arm.links) || []).forEach(function (link, i) {
      linkMeshes[i] = null;
      loadStl(link.mesh, armMaterial, function (mesh) {
        mesh.matrixAutoUpdate = false;
        mesh.name = link.name;
        mesh.visible = false;
        linkMeshes[i] = mesh;
        armGroup.add(mesh);
        updateArm(lastView.arm);
      });
    });

    defaultView = computeDefaultView(c);
    resetCamera();
    cellLoaded = true;
    requestRender();
  }

  // A bin's centre, size and directions in the base frame: `open` points out of the opening
  // (toward the robot at the base origin), `vertical` up, `side` across the opening.
  function binGeometry(bin) {
    const m = matrixFrom(bin.X);
    const e = m.elements;
    const centre = new THREE.Vector3(e[12], e[13], e[14]);
    const depth = new THREE.Vector3(e[0], e[1], e[2]).normalize();
    const toRobot = centre.clone().negate();
    toRobot.z = 0;
    const open = depth.dot(toRobot) >= 0 ? depth : depth.clone().negate();
    return {centre: centre, open: open, size: bin.size_m,
            side: new THREE.Vector3(e[4], e[5], e[6]).normalize(),
            vertical: new THREE.Vector3(e[8], e[9], e[10]).normalize()};
  }

  // Default camera: on the robot's side of the shelf, raised, looking at the bins' centre,
  // a little to the side so that the arm does not hide the middle column.
  function computeDefaultView(c) {
    const bins = c.bins || [];
    const target = new THREE.Vector3();
    if (bins.length) {
      bins.forEach(function (b) { target.add(new THREE.Vector3(b.X[12], b.X[13], b.X[14])); });
      target.divideScalar(bins.length);
    } else if (c.shelf) {
      target.set(c.shelf.X[12], c.shelf.X[13], 0.5);
    } else {
      target.set(1, 0, 0.5);
    }
    // From the shelf toward the robot (horizontal); the robot is at the base origin.
    const back = new THREE.Vector3(-target.x, -target.y, 0);
    if (back.lengthSq() < 1e-6) back.set(-1, 0, 0);
    back.normalize();
    const side = new THREE.Vector3(-back.y, back.x, 0);  // left, seen from the robot
    const position = target.clone()
        .addScaledVector(back, 2.8)
        .addScaledVector(side, -0.25)
        .add(new THREE.Vector3(0, 0, 1.1));
    // Look a little in front of and below the bins so that the arm, tote and table show too.
    const look = target.clone().addScaledVector(back, 0.35).add(new THREE.Vector3(0, 0, -0.12));
    return {position: position, target: look};
  }

  // The camera in front of the item's bin, looking into it.
  function itemView(name) {
    const binName = binOfItem(name);
    const bin = cell && (cell.bins || []).find(function (b) { return b.name === binName; });
    if (!bin) return null;
    const g = binGeometry(bin);
    const position = g.centre.clone().addScaledVector(g.open, 1.45)
        .add(new THREE.Vector3(0, 0, 0.5));
    return {position: position, target: g.centre.clone()};
  }

  let framedItem = false;
  function resetCamera() {
    const v = (FOCUS_ITEM && itemView(FOCUS_ITEM)) || defaultView;
    if (!v) return;
    framedItem = FOCUS_ITEM && v !== defaultView;
    camera.position.copy(v.position);
    controls.target.copy(v.target);
    controls.update();
    requestRender();
  }

  // Outlines the bin of the selected item (?item=) or else of the task's current item.
  function updateBinFocus() {
    const t = lastView.task;
    const item = FOCUS_ITEM || (t && t.state === 'running' ? t.item : '');
    const focusBin = item ? binOfItem(item) : '';
    binLabels.forEach(function (l) {
      const focus = l.name === focusBin;
      l.element.className = 'bin-label' + (focus ? ' focus' : '');
      l.edges.material.color.setHex(focus ? COLORS.target : COLORS.binEdge);
      l.edges.material.opacity = focus ? 1 : 0.35;
    });
    requestRender();
  }

  function binOfItem(name) {
    const row = (lastView.items || []).find(function (i) { return i.item === name; });
    return row ? row.bin : '';
  }

  document.getElementById('reset-view').addEventListener('click', function (e) {
    e.preventDefault();
    resetCamera();
  });

  // ---------------------------------------------------------------------------------------
  // Live parts: arm, scan, detections, path

  const gripperMaterial = lambert(COLORS.gripper);
  const gripperMeshes = [];
  let linksDrawn = 0;

  function updateArm(arm) {
    linksDrawn = 0;
    const links = arm && arm.links ? arm.links : [];
    linkMeshes.forEach(function (mesh, i) {
      if (!mesh) return;
      mesh.visible = Array.isArray(links[i]) && links[i].length === 16;
      if (mesh.visible) {
        mesh.matrix.fromArray(links[i]);
        mesh.matrixWorldNeedsUpdate = true;
        linksDrawn++;
      }
    });
    // The gripper: a cylinder per segment between the given end points.
    const segments = arm && arm.gripper ? arm.gripper : [];
    segments.forEach(function (segment, i) {
      if (!gripperMeshes[i]) {
        gripperMeshes[i] = new THREE.Mesh(new THREE.CylinderBufferGeometry(1, 1, 1, 20),
                                          gripperMaterial);
        armGroup.add(gripperMeshes[i]);
      }
      const mesh = gripperMeshes[i];
      const from = new THREE.Vector3().fromArray(segment.from);
      const to = new THREE.Vector3().fromArray(segment.to);
      const axis = to.clone().sub(from);
      const length = axis.length();
      const r = segment.radius_m || 0.02;
      mesh.visible = length > 1e-6;
      if (!mesh.visible) return;
      mesh.position.copy(from).addScaledVector(axis, 0.5);
      mesh.quaternion.setFromUnitVectors(new THREE.Vector3(0, 1, 0), axis.normalize());
      mesh.scale.set(r, length, r);
    });
    for (let i = segments.length; i < gripperMeshes.length; i++) gripperMeshes[i].visible = false;
    requestRender();
  }

  let scanPoints = 0;
  const scanMaterial = new THREE.PointsMaterial({
    color: COLORS.scan, size: 0.004, sizeAttenuation: true, transparent: true, opacity: 0.85,
  });

  function updateScan(scan) {
    scanGroup.children.slice().forEach(function (child) {
      scanGroup.remove(child);
      child.geometry.dispose();
    });
    scanPoints = 0;
    const flat = scan && scan.points_m ? scan.points_m : [];
    const n = Math.floor(flat.length / 3);
    // Until the task's first view there is nothing to draw: the legend says so.
    setText('scan-legend', n > 0 ? 'latest scan' + (scan.item ? ' (' + scan.item + ')' : '')
                                 : 'latest scan: none yet');
    if (n > 0) {
      const geometry = new THREE.BufferGeometry();
      setPositions(geometry, new Float32Array(flat.slice(0, n * 3)));
      scanGroup.add(new THREE.Points(geometry, scanMaterial));
      scanPoints = n;
    }
    requestRender();
  }

  // Item models (STL meshes or PLY, in the item frame): loaded once per URL.
  const modelCache = new Map();  // url -> Promise<BufferGeometry>
  function loadModel(url) {
    if (!modelCache.has(url)) {
      const loader = /\.stl$/i.test(url) ? stlLoader : plyLoader;
      modelCache.set(url, new Promise(function (resolve, reject) {
        loader.load(url, resolve, undefined, reject);
      }));
    }
    return modelCache.get(url);
  }

  // The item whose detection is highlighted: the one asked for in the URL, else the task's
  // current item, else the item of the path or of the scan.
  function targetItem() {
    const v = lastView;
    if (FOCUS_ITEM) return FOCUS_ITEM;
    if (v.task && v.task.item) return v.task.item;
    if (v.path && v.path.item) return v.path.item;
    if (v.scan && v.scan.item) return v.scan.item;
    return '';
  }

  let detectionsDrawn = 0;
  let detectionGeneration = 0;
  const detectionLabels = [];  // {element, corners: [Vector3 x 8] in the base frame}

  function clearDetections() {
    detectionGroup.children.slice().forEach(function (child) { detectionGroup.remove(child); });
    detectionLabels.forEach(function (l) { l.element.remove(); });
    detectionLabels.length = 0;
  }

  function updateDetections(detections) {
    const generation = ++detectionGeneration;
    clearDetections();
    detectionsDrawn = 0;
    // The target's detection; when no detection is of the target item, the first one.
    let target = targetItem();
    const list = detections || [];
    if (list.length && !list.some(function (d) { return d.item === target; })) {
      target = list[0].item;
    }
    list.forEach(function (d) {
      const isTarget = d.item === target;
      const color = isTarget ? COLORS.target : COLORS.other;
      const group = new THREE.Group();
      place(group, d.X);
      // The target is drawn over everything (no depth test) so that the arm in front of the
      // bin never hides it; the others are ordinary solids. It is "transparent" at full
      // opacity: transparent objects (the scan points) are drawn after all opaque ones, and
      // among them by renderOrder. It still writes depth, so that its outline, drawn next
      // with the depth test, shows only the visible edges.
      const overlay = isTarget ? {depthTest: false, transparent: true, opacity: 1} : {};
      const renderOrder = isTarget ? 10 : 0;
      const size = d.box_m && d.box_m.length === 3 ? d.box_m : [0.05, 0.05, 0.05];
      const boxGeometry = new THREE.BoxBufferGeometry(size[0], size[1], size[2]);
      // The model's bounds need not be centred on the item frame (a scanned model's).
      const centre = d.box_center_m && d.box_center_m.length === 3 ? d.box_center_m : [0, 0, 0];
      boxGeometry.translate(centre[0], centre[1], centre[2]);
      const edges = new THREE.LineSegments(new THREE.EdgesGeometry(boxGeometry),
          new THREE.LineBasicMaterial(isTarget ?
              {color: COLORS.targetEdge, transparent: true, opacity: 1} : {color: color}));
      edges.renderOrder = renderOrder + 1;
      group.add(edges);
      detectionGroup.add(group);

      const addBox = function () {
        const mesh = new THREE.Mesh(boxGeometry, lambert(color, overlay));
        mesh.renderOrder = renderOrder;
        group.add(mesh);
      };
      const drawn = function () {
        if (generation !== detectionGeneration) return;
        detectionsDrawn++;
        requestRender();
      };
      if (d.model) {
        loadModel(d.model).then(function (geometry) {
          if (generation !== detectionGeneration) return;
          let object;
          if (geometry.index || /\.stl$/i.test(d.model)) {  // a triangle mesh
            if (!geometry.attributes.normal) geometry.computeVertexNormals();
            object = new THREE.Mesh(geometry, lambert(color, overlay));
          } else {               // a point cloud (the scanned models are)
            object = new THREE.Points(geometry, new THREE.PointsMaterial(Object.assign(
                {color: color, size: 0.005, sizeAttenuation: true}, overlay)));
          }
          object.renderOrder = renderOrder;
          group.add(object);
          drawn();
        }).catch(function (error) {
          console.error('cannot load model ' + d.model, error);
          if (generation !== detectionGeneration) return;
          addBox();
          drawn();
        });
      } else {
        addBox();
        drawn();
      }

      // The target's label above the item: anchored at the box corners, placed after each
      // frame. (Only the target's: other labels could cover it.)
      if (!isTarget) return;
      group.updateMatrixWorld(true);
      const corners = [];
      for (let i = 0; i < 8; i++) {
        corners.push(new THREE.Vector3((i & 1 ? 0.5 : -0.5) * size[0], (i & 2 ? 0.5 : -0.5) * size[1],
                                       (i & 4 ? 0.5 : -0.5) * size[2]).applyMatrix4(group.matrix));
      }
      const element = document.createElement('div');
      element.className = 'label' + (isTarget ? ' target' : '');
      const score = typeof d.score === 'number' ? ' ' + d.score.toFixed(2) : '';
      element.textContent = d.item + score;
      labelsElement.appendChild(element);
      detectionLabels.push({element: element, corners: corners});
    });
    requestRender();
  }

  function updatePath(path) {
    pathGroup.children.slice().forEach(function (child) {
      pathGroup.remove(child);
      child.geometry.dispose();
    });
    const points = path && path.tcp_m ? path.tcp_m : [];
    if (points.length >= 2) {
      const flat = new Float32Array(points.length * 3);
      points.forEach(function (p, i) { flat.set(p, i * 3); });
      const geometry = new THREE.BufferGeometry();
      setPositions(geometry, flat);
      pathGroup.add(new THREE.Line(geometry, new THREE.LineBasicMaterial({color: COLORS.path})));
      const dots = new THREE.BufferGeometry();
      setPositions(dots, new Float32Array(flat));
      pathGroup.add(new THREE.Points(dots, new THREE.PointsMaterial(
          {color: COLORS.path, size: 6, sizeAttenuation: false})));
    }
    requestRender();
  }

  // ---------------------------------------------------------------------------------------
  // HTML labels over the canvas

  const labelsElement = document.getElementById('labels');
  const projected = new THREE.Vector3();

  function toScreen(point) {
    projected.copy(point).project(camera);
    if (projected.z > 1 || projected.z < -1) return null;
    return {x: (projected.x + 1) / 2 * canvas.clientWidth,
            y: (1 - projected.y) / 2 * canvas.clientHeight};
  }

  function updateLabels() {
    binLabels.forEach(function (l) {
      const p = toScreen(l.anchor);
      l.element.style.display = p ? '' : 'none';
      if (p) l.element.style.transform = 'translate(' + (p.x + 3) + 'px,' + (p.y + 2) + 'px)';
    });
    // A detection's label sits above the topmost projected corner of its box, so it never
    // covers the item itself.
    detectionLabels.forEach(function (l) {
      let top = null;
      let sumX = 0;
      let n = 0;
      l.corners.forEach(function (c) {
        const p = toScreen(c);
        if (!p) return;
        sumX += p.x;
        n++;
        if (top === null || p.y < top) top = p.y;
      });
      l.element.style.display = n ? '' : 'none';
      if (n) {
        l.element.style.transform = 'translate(' + (sumX / n) + 'px,' + (top - 6) + 'px) ' +
                                    'translate(-50%, -100%)';
      }
    });
  }

  // ---------------------------------------------------------------------------------------
  // Panel

  const $ = function (id) { return document.getElementById(id); };
  let lastView = {status: null, task: null, items: [], arm: null, scan: null, detections: [],
                  path: null, log: []};
  let taskReceivedAt = 0;  // performance.now() when task.time_s was received
  let streamDown = false;
  let viewError = '';

  function formatClock(seconds) {
    const sign = seconds < 0 ? '-' : '';
    const s = Math.floor(Math.abs(seconds));
    return sign + Math.floor(s / 60) + ':' + String(s % 60).padStart(2, '0');
  }

  function setText(id, text) {
    const element = $(id);
    if (element.textContent !== text) element.textContent = text;
  }

  function renderStatus() {
    const status = lastView.status || {};
    let text = '';
    let level = 'ok';
    if (viewError) {
      text = viewError;
      level = 'bad';
    } else if (streamDown) {
      text = 'reconnecting to the viewer server\u2026';
      level = 'warn';
    } else if (status.message) {
      text = status.message;
      level = status.orchestrator === 'unreachable' ? 'bad' : (lastView.task ? 'ok' : 'warn');
    } else if (status.orchestrator === 'unreachable') {
      text = 'orchestrator not reachable \u2014 retrying';
      level = 'bad';
    } else if (!lastView.task) {
      text = TASK_ID ? "no task '" + TASK_ID + "' \u2014 retrying" : 'waiting for a task';
      level = 'warn';
    } else {
      text = 'connected';
    }
    const element = $('status');
    setText('status', text);
    element.className = 'status' + (level === 'ok' ? '' : ' ' + level);

    const armMissing = !lastView.arm || status.robot === 'unreachable';
    const armElement = $('arm-status');
    armElement.hidden = !armMissing;
    setText('arm-status', status.robot === 'unreachable'
        ? 'arm not connected (robot server not reachable) \u2014 the arm is not drawn'
        : 'no arm state yet \u2014 the arm is not drawn');
  }

  function renderTask() {
    const t = lastView.task;
    const banner = $('banner');
    const finished = $('finished');
    if (!t) {
      setText('task-id', 'no task');
      setText('task-kind', '');
      setText('task-state', '\u2013');
      $('task-state').className = 'state-badge';
      ['task-step', 'task-item', 'task-done', 'score', 'time-left'].forEach(function (id) {
        setText(id, '\u2013');
      });
      setText('task-message', '');
      banner.hidden = true;
      finished.hidden = true;
      return;
    }
    setText('task-id', t.task_id || '');
    setText('task-kind', t.kind || '');
    setText('task-state', t.state || '');
    $('task-state').className = 'state-badge ' + (t.state || '');
    setText('task-step', t.step || '\u2013');
    setText('task-item', t.item || '\u2013');
    setText('task-done', (t.items_done || 0) + ' / ' + (t.items_total || 0));
    setText('score', String(Math.round(t.score || 0)));
    setText('task-message', t.message || '');
    renderClock();
    const over = t.state && t.state !== 'running';
    banner.hidden = !over;
    finished.hidden = !over;
    if (over) {
      const text = 'Task finished: ' + t.state + ' \u2014 final score ' + Math.round(t.score || 0);
      banner.textContent = text;
      banner.className = 'banner ' + t.state;
      finished.textContent = text;
      finished.className = 'finished ' + t.state;
    }
  }

  // Time left on the task clock; counts down locally between task events while running.
  function renderClock() {
    const t = lastView.task;
    if (!t || typeof t.time_limit_s !== 'number' || !(t.time_limit_s > 0)) {
      setText('time-left', '\u2013');
      return;
    }
    let elapsed = t.time_s || 0;
    if (t.state === 'running') elapsed += (performance.now() - taskReceivedAt) / 1000;
    setText('time-left', formatClock(t.time_limit_s - elapsed) +
                         (t.state === 'running' ? '' : ' (stopped)'));
  }
  setInterval(renderClock, 500);

  function itemDetail(row) {
    if (row.state === 'failed' && row.reason) return row.reason;
    const parts = [];
    if (row.method) parts.push(row.method);
    if (typeof row.score === 'number' && (row.method || row.score)) parts.push(row.score.toFixed(2));
    if (row.attempts > 1) parts.push(row.attempts + ' attempts');
    if (row.reason) parts.push(row.reason);
    return parts.join(' \u00b7 ');
  }

  function renderItems() {
    const body = $('work-order').tBodies[0];
    const items = lastView.items || [];
    const current = lastView.task && lastView.task.state === 'running' ? lastView.task.item : '';
    // Rebuild only when the rows change, so a hover or selection is not lost on every event.
    while (body.rows.length > items.length) body.deleteRow(-1);
    items.forEach(function (row, i) {
      let tr = body.rows[i];
      if (!tr) {
        tr = body.insertRow(-1);
        for (let c = 0; c < 4; c++) tr.insertCell(-1);
        tr.cells[0].className = 'name';
        tr.cells[1].className = 'bin';
        tr.cells[3].className = 'detail';
      }
      const state = row.state || 'waiting';
      tr.className = 'item' + (row.item === FOCUS_ITEM ? ' focus' : '') +
                     (row.item === current && row.item !== FOCUS_ITEM ? ' current' : '');
      tr.dataset.item = row.item;
      tr.dataset.state = state;
      if (tr.cells[0].textContent !== row.item) tr.cells[0].textContent = row.item;
      const bin = (row.bin || '').replace(/^bin_/, '');
      if (tr.cells[1].textContent !== bin) tr.cells[1].textContent = bin;
      const pill = '<span class="pill ' + (STATES.indexOf(state) >= 0 ? state : '') + '"></span>';
      if (!tr.cells[2].firstChild || tr.cells[2].firstChild.textContent !== state) {
        tr.cells[2].innerHTML = pill;
        tr.cells[2].firstChild.textContent = state;
      }
      const detail = itemDetail(row);
      if (tr.cells[3].textContent !== detail) tr.cells[3].textContent = detail;
    });
    $('no-items').hidden = items.length > 0;
  }

  function renderLog() {
    const list = $('log');
    list.textContent = '';
    const entries = (lastView.log || []).slice(-20).reverse();  // newest first
    entries.forEach(function (e) {
      const li = document.createElement('li');
      if (e.ok === false) li.className = 'fail';
      const time = document.createElement('span');
      time.className = 't';
      time.textContent = formatClock(e.time_s || 0);
      const step = document.createElement('span');
      step.className = 's';
      step.textContent = e.step || '\u00b7';
      li.append(time, step, (e.item ? e.item + ': ' : '') + (e.message || ''));
      list.appendChild(li);
    });
  }

  // ---------------------------------------------------------------------------------------
  // Data flow

  // Applies one part of the snapshot (an event of /api/stream, or all of /api/view).
  function apply(part, data) {
    switch (part) {
      case 'status':
        lastView.status = data;
        renderStatus();
        break;
      case 'task':
        lastView.task = data ? data.task : null;
        if (data && 'items' in data) lastView.items = data.items || [];
        if (data && 'log' in data) lastView.log = data.log || [];
        taskReceivedAt = performance.now();
        renderTask();
        renderItems();
        renderLog();
        renderStatus();
        updateBinFocus();
        // The target may have changed: recolour the detections.
        updateDetections(lastView.detections);
        break;
      case 'arm':
        lastView.arm = data;
        updateArm(data);
        renderStatus();
        break;
      case 'scan':
        lastView.scan = data;
        updateScan(data);
        break;
      case 'detections':
        lastView.detections = data || [];
        updateDetections(lastView.detections);
        break;
      case 'path':
        lastView.path = data;
        updatePath(data);
        break;
    }
  }

  function applyView(view) {
    apply('status', view.status || null);
    apply('task', {task: view.task || null, items: view.items || [], log: view.log || []});
    apply('arm', view.arm || null);
    apply('scan', view.scan || null);
    apply('path', view.path || null);
    apply('detections', view.detections || []);
  }

  function fetchJson(url) {
    return fetch(url, {cache: 'no-store'}).then(function (response) {
      if (!response.ok) throw new Error(url + ': HTTP ' + response.status);
      return response.json();
    });
  }

  // Retries until it works: the viewer server may be starting or restarting.
  function loadCell() {
    return fetchJson('/api/cell').then(function (c) {
      buildCell(c);
    }).catch(function (error) {
      viewError = 'viewer server not reachable (' + error.message + ') \u2014 retrying';
      renderStatus();
      return new Promise(function (resolve) { setTimeout(resolve, 2000); }).then(loadCell);
    });
  }

  function loadView() {
    return fetchJson('/api/view' + taskQuery).then(function (view) {
      viewError = '';
      applyView(view);
      viewLoaded = true;
      requestRender();
    }).catch(function (error) {
      viewError = 'viewer server not reachable (' + error.message + ') \u2014 retrying';
      renderStatus();
      return new Promise(function (resolve) { setTimeout(resolve, 2000); }).then(loadView);
    });
  }

  function openStream() {
    const source = new EventSource('/api/stream' + taskQuery);
    ['status', 'task', 'arm', 'scan', 'detections', 'path'].forEach(function (part) {
      source.addEventListener(part, function (event) {
        let data;
        try {
          data = JSON.parse(event.data);
        } catch (e) {
          console.error('bad ' + part + ' event', e);
          return;
        }
        apply(part, data);
      });
    });
    source.onopen = function () {
      streamDown = false;
      viewError = '';
      renderStatus();
    };
    // EventSource reconnects by itself; the server sends every part again on connect.
    source.onerror = function () {
      streamDown = source.readyState !== EventSource.OPEN;
      renderStatus();
    };
  }

  // The cell first (the camera needs the bins), then the snapshot, then the live stream.
  loadCell().then(loadView).then(function () {
    if (FOCUS_ITEM && !framedItem) resetCamera();  // the item's bin is known now
    openStream();
  });
  requestRender();

  // ---------------------------------------------------------------------------------------
  // For tests and the console.

  window.pickingViewer = {
    get ready() { return ready && framesRendered > 0; },
    get counts() {
      return {detectionsDrawn: detectionsDrawn, scanPoints: scanPoints, linksDrawn: linksDrawn};
    },
    get lastView() { return lastView; },
    cameraMatrices: function () {
      camera.updateMatrixWorld();
      const rect = canvas.getBoundingClientRect();
      return {
        view: Array.from(camera.matrixWorldInverse.elements),
        projection: Array.from(camera.projectionMatrix.elements),
        width: canvas.clientWidth,
        height: canvas.clientHeight,
        left: rect.left,            // the canvas's offset in the page (CSS px)
        top: rect.top,
        devicePixelRatio: window.devicePixelRatio || 1,
      };
    },
    // Moves the camera (base-frame position and target, 3 numbers each); resolves once the
    // new view is on the canvas. The test looks at a detection from a second direction.
    setView: function (position, target) {
      camera.position.fromArray(position);
      controls.target.fromArray(target);
      controls.update();
      requestRender();
      return new Promise(function (resolve) {
        window.requestAnimationFrame(function () { window.requestAnimationFrame(resolve); });
      });
    },
    resetView: resetCamera,
    get framesRendered() { return framesRendered; },
    scene: scene,
    camera: camera,
    render: requestRender,
  };
})();
