// orthomvp view, 3D: the DEM window around a clicked post draped with the chosen layer, the
// cameras (far ones drawn nearer, along their true direction) and their rays to the first hit.
// Local frame: metres east (x), north (y) and up (z) of the post; rotate by dragging, zoom with
// the wheel (three.js OrbitControls).
import * as THREE from "three";
import { OrbitControls } from "./vendor/three-0.159.0/OrbitControls.js";

const box = document.getElementById("three");
let renderer = null, scene = null, camera = null, controls = null;

function init() {
  box.style.display = "block";
  renderer = new THREE.WebGLRenderer({ antialias: true, preserveDrawingBuffer: true });
  renderer.setSize(box.clientWidth, box.clientHeight);
  box.appendChild(renderer.domElement);
  camera = new THREE.PerspectiveCamera(45, box.clientWidth / box.clientHeight, 1, 1e8);
  camera.up.set(0, 0, 1);
  controls = new OrbitControls(camera, renderer.domElement);
  controls.addEventListener("change", draw);
  const caption = document.createElement("div");
  caption.className = "caption";
  box.appendChild(caption);
}

function draw() { renderer.render(scene, camera); }

function surface(s) {
  const [rows, cols] = s.shape;
  const pos = [], uv = [], index = [];
  for (let i = 0; i < rows; i++) for (let j = 0; j < cols; j++) {
    const k = i * cols + j;
    pos.push(s.x[k], s.y[k], s.z[k] === null ? 0 : s.z[k]);
    uv.push((j + 0.5) / cols, 1 - (i + 0.5) / rows);
  }
  const ok = (k) => s.z[k] !== null;
  for (let i = 0; i + 1 < rows; i++) for (let j = 0; j + 1 < cols; j++) {
    const a = i * cols + j, b = a + 1, c = a + cols, d = c + 1;
    if (ok(a) && ok(b) && ok(c) && ok(d)) index.push(a, c, b, b, c, d);
  }
  const g = new THREE.BufferGeometry();
  g.setAttribute("position", new THREE.Float32BufferAttribute(pos, 3));
  g.setAttribute("uv", new THREE.Float32BufferAttribute(uv, 2));
  g.setIndex(index);
  const tex = new THREE.TextureLoader().load(s.texture, draw);
  tex.colorSpace = THREE.SRGBColorSpace;
  tex.magFilter = THREE.NearestFilter;
  return new THREE.Mesh(g, new THREE.MeshBasicMaterial({ map: tex, side: THREE.DoubleSide }));
}

function line(a, b, colour) {
  const g = new THREE.BufferGeometry().setFromPoints([new THREE.Vector3(...a), new THREE.Vector3(...b)]);
  return new THREE.Line(g, new THREE.LineBasicMaterial({ color: colour }));
}

function dot(p, colour, size) {
  const m = new THREE.Mesh(new THREE.SphereGeometry(size, 12, 8), new THREE.MeshBasicMaterial({ color: colour }));
  m.position.set(...p);
  return m;
}

function show(s) {
  if (!renderer) init();
  scene = new THREE.Scene();
  scene.background = new THREE.Color(0x111111);
  scene.add(surface(s));
  const r = s.spacing * Math.max(...s.shape) / 2;
  scene.add(dot([0, 0, 0], 0xff4fd8, r / 60));
  let text = `post (${s.post[0]}, ${s.post[1]}), draped: ${s.layer}`;
  s.views.forEach((v) => {
    if (!v.camera) { text += `<br>${v.name}: ${v.code}, outside the image`; return; }
    scene.add(dot(v.camera, v.colour, r / 30));
    scene.add(line(v.camera, v.hit || [0, 0, 0], v.colour));
    if (v.hit) scene.add(dot(v.hit, v.hit_colour, r / 45));
    text += `<br><span style="color:${v.colour}">&#9679;</span> ${v.name}: ${v.code}, ` +
      `${(v.distance / 1000).toFixed(1)} km away`;
  });
  box.querySelector(".caption").innerHTML = text;
  camera.position.set(-1.2 * r, -1.6 * r, 1.4 * r);
  camera.near = r / 100; camera.far = r * 1000; camera.updateProjectionMatrix();
  controls.target.set(0, 0, 0);
  controls.update();
  draw();
}

window.orthomvp3d = { show: show, get camera() { return camera; }, get canvas() { return renderer && renderer.domElement; } };
