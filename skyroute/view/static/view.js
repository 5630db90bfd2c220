// The live view: a three.js scene of the city, the plan, the flown track and the vehicle, fed by /ws.
// Map frame (north, east, up, metres) -> three.js (x = east, y = up, z = -north). Protocol: skyroute/view/live.py.
import * as THREE from 'three';
import { OrbitControls } from '/static/vendor/three/OrbitControls.js';

const toScene = (north, east, up) => new THREE.Vector3(east, up, -north);
const view = { messages: 0, state: null, planId: 0, trackLength: 0, obstacles: 0, connected: false };
window.skyrouteView = view;  // for tests and the curious: what the page has received

// ------------------------------------------------------------------------------------------------ scene
const canvas = document.getElementById('scene');
const renderer = new THREE.WebGLRenderer({ canvas, antialias: true, preserveDrawingBuffer: true });
renderer.setPixelRatio(window.devicePixelRatio);
const scene = new THREE.Scene();
scene.background = new THREE.Color(0xcfd8dc);
const camera = new THREE.PerspectiveCamera(50, 1, 1, 20000);
camera.position.set(0, 300, 400);
const controls = new OrbitControls(camera, canvas);
controls.maxPolarAngle = Math.PI * 0.495;
scene.add(new THREE.HemisphereLight(0xffffff, 0x8d8d8d, 2.2));
const sun = new THREE.DirectionalLight(0xffffff, 1.6);
sun.position.set(-300, 600, 200);
scene.add(sun);

function resize() {
  const w = window.innerWidth, h = window.innerHeight;
  renderer.setSize(w, h, false);
  camera.aspect = w / h;
  camera.updateProjectionMatrix();
}
window.addEventListener('resize', resize);
resize();

function boxesMesh(boxes, colourOf) {
  const geometry = new THREE.BoxGeometry(1, 1, 1);
  const material = new THREE.MeshLambertMaterial();
  const mesh = new THREE.InstancedMesh(geometry, material, Math.max(boxes.length, 1));
  const m = new THREE.Matrix4(), q = new THREE.Quaternion(), c = new THREE.Color();
  boxes.forEach(([n, e, alt, hn, he, ha], i) => {
    m.compose(toScene(n, e, alt), q, new THREE.Vector3(2 * he, 2 * ha, 2 * hn));
    mesh.setMatrixAt(i, m);
    mesh.setColorAt(i, colourOf(alt + ha, c));
  });
  mesh.count = boxes.length;
  return mesh;
}

function drawCity(msg) {
  const boxes = msg.boxes || [];
  const top = Math.max(1, ...boxes.map(b => b[2] + b[5]));
  const flight = msg.altitude_m || 0, margin = msg.safety_m || 0;
  scene.add(boxesMesh(boxes, (h, c) => {
    const t = Math.min(h / top, 1);
    return h + margin <= flight ? c.setRGB(0.86, 0.86, 0.84) : c.setRGB(0.72 - 0.4 * t, 0.74 - 0.4 * t, 0.78 - 0.35 * t);
  }));
  let minN = -50, maxN = 50, minE = -50, maxE = 50;
  for (const [n, e, , hn, he] of boxes) {
    minN = Math.min(minN, n - hn); maxN = Math.max(maxN, n + hn);
    minE = Math.min(minE, e - he); maxE = Math.max(maxE, e + he);
  }
  const ground = new THREE.Mesh(new THREE.PlaneGeometry(maxE - minE + 200, maxN - minN + 200),
                                new THREE.MeshLambertMaterial({ color: 0xa5b59a }));
  ground.rotation.x = -Math.PI / 2;
  ground.position.copy(toScene((minN + maxN) / 2, (minE + maxE) / 2, -0.05));
  scene.add(ground);
  const marker = (n, e, colour) => {
    const pin = new THREE.Mesh(new THREE.CylinderGeometry(2, 2, 0.6, 24), new THREE.MeshBasicMaterial({ color: colour }));
    pin.position.copy(toScene(n, e, 0.3));
    scene.add(pin);
  };
  marker(0, 0, 0x2ca02c);  // home
  if (msg.goal) marker(msg.goal[0], msg.goal[1], 0xd62728);
  if (msg.start) marker(msg.start[0], msg.start[1], 0x1f77b4);
  const [gn, ge] = msg.goal || [0, 0];
  controls.target.copy(toScene(gn / 2, ge / 2, 0));
  const span = Math.max(150, Math.hypot(gn, ge));
  camera.position.copy(toScene(gn / 2 - 0.55 * span, ge / 2 - 0.15 * span, 0.75 * span));  // from the south, high
  controls.update();
}

// ------------------------------------------------------------------------------------------------- plan
const plans = [];  // tubes, newest last; earlier ones (replans) fade
function drawPlan(plan) {
  if (!plan || !plan.waypoints || plan.waypoints.length < 1) return;
  const points = plan.waypoints.map(([n, e, a]) => toScene(n, e, a));
  if (points.length === 1) points.push(points[0].clone().add(new THREE.Vector3(0, 0.01, 0)));
  const path = new THREE.CurvePath();
  for (let i = 0; i + 1 < points.length; i++) path.add(new THREE.LineCurve3(points[i], points[i + 1]));
  const tube = new THREE.Mesh(new THREE.TubeGeometry(path, Math.max(8, 4 * points.length), 0.5, 8, false),
                              new THREE.MeshLambertMaterial({ color: 0x1f77b4, transparent: true, opacity: 0.8 }));
  for (const old of plans) { old.material.color.set(0x9ecae1); old.material.transparent = true; old.material.opacity = 0.5; }
  plans.push(tube);
  scene.add(tube);
  view.planId = plan.id;
}

// ------------------------------------------------------------------------------------------------ track
let trackCapacity = 4096;
let trackPositions = new Float32Array(trackCapacity * 3);
const trackGeometry = new THREE.BufferGeometry();
trackGeometry.setAttribute('position', new THREE.BufferAttribute(trackPositions, 3));
trackGeometry.setDrawRange(0, 0);
const track = new THREE.Line(trackGeometry, new THREE.LineBasicMaterial({ color: 0xd62728 }));
track.frustumCulled = false;
scene.add(track);
// The line is one pixel wide: the track is also drawn as a tube, in pieces of TUBE_BATCH points.
const TUBE_BATCH = 10, trackMaterial = new THREE.MeshLambertMaterial({ color: 0xd62728 });
let tubedUpTo = 0;
function tubeTrack() {
  if (view.trackLength - tubedUpTo < TUBE_BATCH) return;
  const from = Math.max(0, tubedUpTo - 1), points = [];
  for (let i = from; i < view.trackLength; i++) {
    points.push(new THREE.Vector3(trackPositions[3 * i], trackPositions[3 * i + 1], trackPositions[3 * i + 2]));
  }
  const path = new THREE.CurvePath();
  for (let i = 0; i + 1 < points.length; i++) {
    if (points[i].distanceTo(points[i + 1]) > 1e-3) path.add(new THREE.LineCurve3(points[i], points[i + 1]));
  }
  if (path.curves.length > 0) {
    scene.add(new THREE.Mesh(new THREE.TubeGeometry(path, 2 * path.curves.length, 0.7, 6, false), trackMaterial));
  }
  tubedUpTo = view.trackLength;
}

function appendTrack(chunk) {
  if (chunk.from !== view.trackLength) console.warn(`track: expected ${view.trackLength}, got ${chunk.from}`);
  for (const [, n, e, a] of chunk.items) {
    if (view.trackLength >= trackCapacity) {
      trackCapacity *= 2;
      const bigger = new Float32Array(trackCapacity * 3);
      bigger.set(trackPositions);
      trackPositions = bigger;
      trackGeometry.setAttribute('position', new THREE.BufferAttribute(trackPositions, 3));
    }
    const p = toScene(n, e, a);
    trackPositions.set([p.x, p.y, p.z], 3 * view.trackLength);
    view.trackLength += 1;
  }
  trackGeometry.attributes.position.needsUpdate = true;
  trackGeometry.setDrawRange(0, view.trackLength);
  tubeTrack();
}

// ---------------------------------------------------------------------------------------------- vehicle
const vehicle = new THREE.Group();
const body = new THREE.Mesh(new THREE.SphereGeometry(1, 16, 12), new THREE.MeshLambertMaterial({ color: 0xffbf00 }));
const nose = new THREE.Mesh(new THREE.ConeGeometry(0.8, 2.6, 12), new THREE.MeshLambertMaterial({ color: 0xd62728 }));
nose.rotation.x = -Math.PI / 2;  // cone's +y to -z: "forward" = north when heading is 0
nose.position.set(0, 0, -1.8);
const shadow = new THREE.Mesh(new THREE.CircleGeometry(1.2, 24),
                              new THREE.MeshBasicMaterial({ color: 0x333333, transparent: true, opacity: 0.35 }));
shadow.rotation.x = -Math.PI / 2;
vehicle.add(body, nose);
vehicle.visible = shadow.visible = false;
scene.add(vehicle, shadow);

function placeVehicle(v) {
  if (!v) return;
  const p = toScene(v.north_m, v.east_m, v.altitude_m);
  const moved = p.clone().sub(vehicle.position);
  const first = !vehicle.visible;
  vehicle.position.copy(p);
  shadow.position.copy(toScene(v.north_m, v.east_m, 0.08));
  if (v.heading_rad !== null) vehicle.rotation.y = -v.heading_rad;  // heading clockwise from north
  vehicle.visible = shadow.visible = true;
  if (document.getElementById('follow').checked) {
    if (first) { controls.target.copy(p); } else { controls.target.add(moved); camera.position.add(moved); }
  }
}

// ----------------------------------------------------------------------------- sensing and exploration
const found = [];
function appendObstacles(chunk) {
  const mesh = boxesMesh(chunk.items, (h, c) => c.setRGB(1.0, 0.5, 0.05));
  scene.add(mesh);
  found.push(mesh);
  view.obstacles += chunk.items.length;
}

let knownMesh = null;
function drawKnownArea(area) {
  if (knownMesh) { scene.remove(knownMesh); knownMesh.geometry.dispose(); knownMesh.material.map.dispose(); }
  if (!area || !area.rows || !area.cols) return;
  const data = new Uint8Array(area.rows * area.cols * 4);
  for (let i = 0; i < area.rows * area.cols; i++) {
    const known = area.known[i] === '1';
    data.set(known ? [255, 255, 255, 60] : [40, 40, 60, 110], 4 * i);
  }
  const texture = new THREE.DataTexture(data, area.cols, area.rows);  // row 0 = southmost (north index 0)
  texture.needsUpdate = true;
  const w = area.cols * area.cell_m, h = area.rows * area.cell_m;
  knownMesh = new THREE.Mesh(new THREE.PlaneGeometry(w, h),
                             new THREE.MeshBasicMaterial({ map: texture, transparent: true, depthWrite: false }));
  knownMesh.rotation.x = -Math.PI / 2;
  knownMesh.position.copy(toScene(area.north_offset_m + h / 2, area.east_offset_m + w / 2, 0.1));
  scene.add(knownMesh);
}

const frontierGeometry = new THREE.BufferGeometry();
const frontiers = new THREE.Points(frontierGeometry, new THREE.PointsMaterial({ color: 0xffd700, size: 3 }));
scene.add(frontiers);
function drawFrontiers(points) {
  const flat = new Float32Array(3 * (points || []).length);
  (points || []).forEach(([n, e], i) => { const p = toScene(n, e, 0.5); flat.set([p.x, p.y, p.z], 3 * i); });
  frontierGeometry.setAttribute('position', new THREE.BufferAttribute(flat, 3));
}

// ------------------------------------------------------------------------------------------------ panel
const text = (id, value) => { document.getElementById(id).textContent = value; };
const fixed = (x, digits, unit) => (x === null || x === undefined ? '-' : `${x.toFixed(digits)} ${unit}`);

function showState(s) {
  view.state = s;
  text('mission-state', s.mission_state);
  text('mode', `${s.mode || '-'}${s.armed ? ', armed' : ''}${s.link_ok ? '' : ', LINK LOST'}`);
  text('speed', fixed(s.speed_mps, 1, 'm/s'));
  text('altitude', s.vehicle ? fixed(s.vehicle.altitude_m, 1, 'm') : '-');
  text('distance', fixed(s.distance_to_go_m, 0, 'm'));
  text('position', s.vehicle ? `N ${s.vehicle.north_m.toFixed(1)}, E ${s.vehicle.east_m.toFixed(1)}` : '-');
  text('time', fixed(s.time_s, 1, 's'));
  placeVehicle(s.vehicle);
}

function showEvents(chunk) {
  const list = document.getElementById('events');
  for (const e of chunk.items) {
    const li = document.createElement('li');
    li.textContent = e.text;
    list.prepend(li);
  }
  while (list.children.length > 5) list.lastChild.remove();
}

// ------------------------------------------------------------------------------------------------ wire
const socket = new WebSocket(`ws://${location.host}/ws`);
socket.addEventListener('open', () => { view.connected = true; text('connection', 'live'); });
socket.addEventListener('close', () => {
  view.connected = false;
  text('connection', 'the flight is over (last state shown)');
});
socket.addEventListener('message', (event) => {
  const msg = JSON.parse(event.data);
  view.messages += 1;
  if (msg.type === 'scene') { drawCity(msg); return; }
  if (msg.type !== 'update') return;
  if (msg.plan) drawPlan(msg.plan);
  if (msg.track) appendTrack(msg.track);
  if (msg.obstacles) appendObstacles(msg.obstacles);
  if (msg.known_area !== undefined) drawKnownArea(msg.known_area);
  if (msg.frontiers !== undefined) drawFrontiers(msg.frontiers);
  if (msg.events) showEvents(msg.events);
  if (msg.state) showState(msg.state);
});

function frame() {
  const d = camera.position.distanceTo(vehicle.position);
  vehicle.scale.setScalar(Math.max(1, d / 60));  // stays visible from afar
  shadow.scale.setScalar(Math.max(1, d / 60));
  controls.update();
  renderer.render(scene, camera);
  requestAnimationFrame(frame);
}
requestAnimationFrame(frame);
