// The 3D scene: cabin (GLB from the service), the robot's collision bodies posed from the scene document,
// markers (start, goal, approach line) and the closest pair. Poses are applied as given (row-major R, p in
// the robot base frame, which is y-up like three.js); nothing is computed here but drawing.
import * as THREE from 'three';
import { OrbitControls } from 'three/addons/controls/OrbitControls.js';
import { GLTFLoader } from 'three/addons/loaders/GLTFLoader.js';

export function webglAvailable() {
  try {
    const probe = document.createElement('canvas');
    const ctx = probe.getContext('webgl2') || probe.getContext('webgl');
    if (!ctx) return false;
    const lose = ctx.getExtension('WEBGL_lose_context');
    if (lose) lose.loseContext();
    return true;
  } catch (err) {
    return false;
  }
}

const BODY_COLOR = 0x8fa3bf;
const PAYLOAD_COLOR = 0xf59e0b;
const HIGHLIGHT = 0xef4444;
const INSTALLED_COLOR = 0x60a5fa;
const FIXTURE_COLOR = 0x92400e;
const BAY_COLOR = 0x22c55e;

function matrixOf(R, p) {
  const m = new THREE.Matrix4();
  m.set(R[0][0], R[0][1], R[0][2], p[0],
    R[1][0], R[1][1], R[1][2], p[1],
    R[2][0], R[2][1], R[2][2], p[2],
    0, 0, 0, 1);
  return m;
}

export class Scene3D {
  constructor(canvas) {
    this.canvas = canvas;
    this.renderer = new THREE.WebGLRenderer({ canvas, antialias: true, preserveDrawingBuffer: true });
    this.renderer.setPixelRatio(window.devicePixelRatio || 1);
    this.scene = new THREE.Scene();
    this.scene.background = new THREE.Color(0x0f141c);
    this.camera = new THREE.PerspectiveCamera(45, 1, 0.02, 200);
    this.camera.position.set(3, 2.5, -2);
    this.controls = new OrbitControls(this.camera, canvas);
    this.controls.addEventListener('change', () => this.render());
    this.scene.add(new THREE.HemisphereLight(0xffffff, 0x334155, 1.6));
    const sun = new THREE.DirectionalLight(0xffffff, 1.8);
    sun.position.set(3, 6, -2);
    this.scene.add(sun);
    this.root = new THREE.Group();
    this.scene.add(this.root);
    this.bodies = [];
    this.cabin = null;
    this.markers = new THREE.Group();
    this.root.add(this.markers);
    this.highlight = [];
    this.renderCount = 0;
    this.pprs6 = null;
    this.task = null;
    this.witness = this._witness();
    this.root.add(this.witness);
    new ResizeObserver(() => this.resize()).observe(canvas);
    this.resize();
  }

  resize() {
    const w = this.canvas.clientWidth || 640;
    const h = this.canvas.clientHeight || 400;
    this.renderer.setSize(w, h, false);
    this.camera.aspect = w / h;
    this.camera.updateProjectionMatrix();
    this.render();
  }

  render() {
    this.renderer.render(this.scene, this.camera);
    this.renderCount += 1;
  }

  clear() {
    for (const obj of [...this.root.children]) if (obj !== this.markers && obj !== this.witness) this.root.remove(obj);
    this.markers.clear();
    this.bodies = [];
    this.cabin = null;
    this.pprs6 = null;
    this.task = null;
    this.highlight = [];
    this.witness.visible = false;
    this.render();
  }

  _witness() {
    const g = new THREE.Group();
    const geom = new THREE.BufferGeometry().setFromPoints([new THREE.Vector3(), new THREE.Vector3()]);
    g.userData.line = new THREE.Line(geom, new THREE.LineBasicMaterial({ color: HIGHLIGHT, depthTest: false }));
    g.userData.line.renderOrder = 10;
    g.add(g.userData.line);
    for (const k of ['a', 'b']) {
      const s = new THREE.Mesh(new THREE.SphereGeometry(0.012, 12, 8),
        new THREE.MeshBasicMaterial({ color: HIGHLIGHT, depthTest: false }));
      s.renderOrder = 10;
      g.userData[k] = s;
      g.add(s);
    }
    g.visible = false;
    return g;
  }

  setBodies(bodies) {
    for (const b of this.bodies) this.root.remove(b.group);
    this.bodies = [];
    for (const spec of bodies) {
      const color = spec.name === 'payload' ? PAYLOAD_COLOR : BODY_COLOR;
      const material = new THREE.MeshStandardMaterial({ color, roughness: 0.6, metalness: 0.1 });
      const group = new THREE.Group();
      group.matrixAutoUpdate = false;
      group.userData = { body: spec.name, kind: spec.kind };
      const entry = { name: spec.name, kind: spec.kind, group, material, baseColor: color, parts: {} };
      if (spec.kind === 'box') {
        const [x, y, z] = spec.size_m;
        group.add(new THREE.Mesh(new THREE.BoxGeometry(x, y, z), material));
      } else {
        const r = spec.radius_m;
        const cyl = new THREE.Mesh(new THREE.CylinderGeometry(r, r, 1, 20, 1, true), material);
        cyl.rotation.x = Math.PI / 2; // three's cylinder runs along y; a capsule's axis is its frame's z
        const a = new THREE.Mesh(new THREE.SphereGeometry(r, 16, 12), material);
        const b = new THREE.Mesh(new THREE.SphereGeometry(r, 16, 12), material);
        group.add(cyl, a, b);
        entry.parts = { cyl, a, b };
      }
      this.root.add(group);
      this.bodies.push(entry);
    }
  }

  async loadCabin(url, key) {
    const loader = new GLTFLoader();
    loader.setRequestHeader({ 'X-API-Key': key });
    const gltf = await loader.loadAsync(url);
    const cabin = gltf.scene;
    const material = new THREE.MeshStandardMaterial({
      color: 0x9ca3af, transparent: true, opacity: 0.16, side: THREE.DoubleSide, depthWrite: false,
    });
    const edges = new THREE.Group();
    cabin.traverse((obj) => {
      if (obj.isMesh) {
        obj.material = material;
        const lines = new THREE.LineSegments(new THREE.EdgesGeometry(obj.geometry, 25),
          new THREE.LineBasicMaterial({ color: 0x64748b, transparent: true, opacity: 0.55 }));
        lines.applyMatrix4(obj.matrixWorld);
        edges.add(lines);
      }
    });
    cabin.add(edges);
    cabin.userData.cabin = true;
    this.cabin = cabin;
    this.root.add(cabin);
    this.render();
  }

  setMarkers(scene) {
    this.markers.clear();
    const pose = (p, size) => {
      const axes = new THREE.AxesHelper(size);
      axes.matrixAutoUpdate = false;
      axes.matrix.copy(matrixOf(p.rotation, p.position));
      return axes;
    };
    if (scene.start) this.markers.add(pose(scene.start, 0.25));
    if (scene.goal) {
      this.markers.add(pose(scene.goal, 0.35));
      const ring = new THREE.Mesh(new THREE.SphereGeometry(0.03, 16, 12), new THREE.MeshBasicMaterial({ color: 0x22c55e }));
      ring.position.fromArray(scene.goal.position);
      this.markers.add(ring);
    }
    if (scene.approach) {
      const geom = new THREE.BufferGeometry().setFromPoints([
        new THREE.Vector3(...scene.approach.from_m), new THREE.Vector3(...scene.approach.to_m)]);
      this.markers.add(new THREE.Line(geom, new THREE.LineBasicMaterial({ color: 0x22d3ee })));
    }
    this.render();
  }

  frameCamera() {
    const box = new THREE.Box3();
    for (const b of this.bodies) { b.group.updateMatrixWorld(true); box.expandByObject(b.group); }
    if (this.pprs6) box.expandByObject(this.pprs6.group);
    if (this.task) box.expandByObject(this.task.group);
    box.expandByObject(this.markers);
    if (box.isEmpty()) return;
    const centre = box.getCenter(new THREE.Vector3());
    const size = box.getSize(new THREE.Vector3()).length();
    this.aimCamera(centre, Math.max(size * 0.8, 0.25), [0.9, 0.7, -0.8]);
  }

  // Put the camera at centre + d * direction (direction in units of d), looking at the centre, with near
  // and far planes scaled to the distance d [m].
  aimCamera(centre, d, direction) {
    const [x, y, z] = direction;
    this.camera.position.set(centre.x + x * d, centre.y + y * d, centre.z + z * d);
    this.camera.near = d / 200;
    this.camera.far = d * 50;
    this.camera.updateProjectionMatrix();
    this.controls.target.copy(centre);
    this.controls.update();
    this.render();
  }

  // A task's view: the robot, the docks and every bay framed from above the aisle, looking across at the
  // bays (the cabin wall is see-through), so that the unit is seen on its dock, carried and in its bay.
  frameTask() {
    if (!this.task) { this.frameCamera(); return; }
    const box = new THREE.Box3();
    for (const b of this.bodies) { b.group.updateMatrixWorld(true); box.expandByObject(b.group); }
    this.task.group.updateMatrixWorld(true);
    box.expandByObject(this.task.group);
    if (box.isEmpty()) return;
    const centre = box.getCenter(new THREE.Vector3());
    const size = box.getSize(new THREE.Vector3()).length();
    this.aimCamera(centre, Math.max(size * 0.55, 0.25), [-0.75, 0.85, -0.35]);
  }

  showFrame(frames, i, closest) {
    const R = frames.R[i];
    const p = frames.p_m[i];
    const L = frames.length_m[i];
    this.bodies.forEach((b, k) => {
      b.group.matrix.copy(matrixOf(R[k], p[k]));
      b.group.matrixWorldNeedsUpdate = true;
      if (b.kind === 'capsule') {
        const len = L[k];
        b.parts.cyl.scale.set(1, Math.max(len, 1e-6), 1);
        b.parts.a.position.set(0, 0, len / 2);
        b.parts.b.position.set(0, 0, -len / 2);
      }
    });
    this.setHighlight(closest ? closest.pair : [], closest && closest.a, closest && closest.b);
    this.render();
  }

  setHighlight(names, a, b) {
    this.highlight = (names || []).filter((n) => n === 'cabin' || this.bodies.some((x) => x.name === n));
    for (const body of this.bodies) {
      const on = this.highlight.includes(body.name);
      body.material.color.setHex(on ? HIGHLIGHT : body.baseColor);
      body.material.emissive.setHex(on ? 0x550000 : 0x000000);
    }
    // The cabin is not recoloured (it would tint the whole view): the witness line and points mark the spot.
    if (a && b) {
      const line = this.witness.userData.line;
      line.geometry.setFromPoints([new THREE.Vector3(...a), new THREE.Vector3(...b)]);
      this.witness.userData.a.position.fromArray(a);
      this.witness.userData.b.position.fromArray(b);
      this.witness.visible = true;
    } else {
      this.witness.visible = false;
    }
  }

  bodyCount() { return this.bodies.length; }
  bodyNames() { return this.bodies.map((b) => b.name); }
  highlighted() { return [...this.highlight]; }

  // The pose of the payload as drawn (its box centre and axes in the base frame), read back from the scene
  // graph; for pprs6 the platform centre.
  payloadPose() {
    let e = null; // column-major
    const body = this.bodies.find((b) => b.name === 'payload');
    if (body) {
      body.group.updateMatrixWorld(true);
      e = body.group.matrixWorld.elements;
    } else if (this.pprs6) {
      e = this.pprs6.platform.matrix.elements; // in the pprs6 base frame (the group turns z-up to y-up)
    }
    if (!e) return null;
    return {
      position: [e[12], e[13], e[14]],
      rotation: [[e[0], e[4], e[8]], [e[1], e[5], e[9]], [e[2], e[6], e[10]]],
    };
  }

  // ------------------------------------------------------------------------------------- cycles, campaigns
  // The fixed obstacles (units installed before, the docks' fixtures), one box per unit the task installs
  // (posed per frame from the scene document: on its dock, held, or in its bay) and a wireframe at every bay.
  setTask(scene) {
    const group = new THREE.Group();
    const solid = (spec, color, opacity = 1) => {
      const material = new THREE.MeshStandardMaterial({ color, roughness: 0.7, transparent: opacity < 1, opacity });
      let geom;
      if (spec.kind === 'mesh') {
        geom = new THREE.BufferGeometry();
        geom.setAttribute('position', new THREE.Float32BufferAttribute(spec.vertices_m.flat(), 3));
        geom.setIndex(spec.faces.flat());
        geom.computeVertexNormals();
      } else {
        geom = new THREE.BoxGeometry(...spec.size_m);
      }
      const mesh = new THREE.Mesh(geom, material);
      mesh.matrixAutoUpdate = false;
      if (spec.position) mesh.matrix.copy(matrixOf(spec.rotation, spec.position));
      mesh.userData = { name: spec.name };
      group.add(mesh);
      return mesh;
    };
    for (const o of scene.installed || []) solid(o, INSTALLED_COLOR, 0.85);
    for (const f of scene.fixtures || []) solid(f, FIXTURE_COLOR, 0.9);
    const units = {};
    for (const u of scene.units || []) {
      if (u.cycle === null || u.cycle === undefined || !u.size_m) continue;
      const box = solid({ kind: 'box', size_m: u.size_m, name: `unit ${u.id}` }, PAYLOAD_COLOR);
      box.visible = false;
      const bay = new THREE.LineSegments(new THREE.EdgesGeometry(new THREE.BoxGeometry(...u.size_m)),
        new THREE.LineBasicMaterial({ color: BAY_COLOR }));
      bay.matrixAutoUpdate = false;
      bay.matrix.copy(matrixOf(u.bay.rotation, u.bay.position));
      group.add(bay);
      units[u.id] = { box, cycle: u.cycle, bay: u.bay, state: 'absent' };
    }
    this.root.add(group);
    this.task = { group, units };
  }

  // Frame i of a task scene: the robot's bodies, and every unit where the scene puts it at that frame.
  showTaskFrame(scene, i, closest) {
    const frames = scene.frames;
    const k = frames.cycle[i];
    if (this.task) {
      for (const [id, u] of Object.entries(this.task.units)) {
        if (u.cycle < k) {
          u.box.matrix.copy(matrixOf(u.bay.rotation, u.bay.position));
          u.state = 'installed';
        } else if (u.cycle === k) {
          const p = frames.unit_pose[i];
          u.box.matrix.copy(matrixOf(p.rotation, p.position));
          u.state = frames.unit_held[i] ? 'held' : (frames.leg[i] >= scene.cycles[k].legs.findIndex((x) => x.name === 'release') ? 'installed' : 'dock');
        } else {
          u.state = 'absent';
        }
        u.box.visible = u.state !== 'absent';
        u.box.matrixWorldNeedsUpdate = true;
        void id;
      }
    }
    this.showFrame(frames, i, closest);
  }

  // Every task unit as drawn: its state (absent, dock, held, installed) and its box pose (base frame).
  taskUnits() {
    if (!this.task) return {};
    const out = {};
    for (const [id, u] of Object.entries(this.task.units)) {
      u.box.updateMatrixWorld(true);
      const e = u.box.matrixWorld.elements;
      out[id] = {
        state: u.state,
        visible: u.box.visible,
        position: [e[12], e[13], e[14]],
        rotation: [[e[0], e[4], e[8]], [e[1], e[5], e[9]], [e[2], e[6], e[10]]],
      };
    }
    return out;
  }

  // --------------------------------------------------------------------------------------------- pprs6
  setPprs6(scene) {
    this.clear();
    const group = new THREE.Group();
    const mat = new THREE.MeshStandardMaterial({ color: BODY_COLOR, roughness: 0.6 });
    const seg = (r) => {
      const m = new THREE.Mesh(new THREE.CylinderGeometry(r, r, 1, 16), mat);
      group.add(m);
      return m;
    };
    const chains = [0, 1, 2].map(() => ({ column: seg(0.006), link: seg(0.004) }));
    const platform = new THREE.Group();
    platform.matrixAutoUpdate = false;
    const r = scene.geometry.r_m;
    const tri = new THREE.BufferGeometry();
    const verts = [];
    for (let k = 0; k < 3; k++) {
      const a = (2 * Math.PI * k) / 3;
      verts.push(r * Math.cos(a), r * Math.sin(a), 0);
    }
    tri.setAttribute('position', new THREE.Float32BufferAttribute(verts, 3));
    tri.setIndex([0, 1, 2]);
    tri.computeVertexNormals();
    platform.add(new THREE.Mesh(tri, new THREE.MeshStandardMaterial({ color: PAYLOAD_COLOR, side: THREE.DoubleSide })));
    platform.add(new THREE.AxesHelper(0.08));
    group.add(platform);
    const R = scene.geometry.R_m;
    const base = new THREE.Mesh(new THREE.CircleGeometry(R * 1.05, 48), new THREE.MeshStandardMaterial({ color: 0x334155, side: THREE.DoubleSide }));
    group.add(base);
    const pts = scene.workspace.points_m;
    if (pts.length) {
      const g = new THREE.BufferGeometry();
      g.setAttribute('position', new THREE.Float32BufferAttribute(pts.flat(), 3));
      group.add(new THREE.Points(g, new THREE.PointsMaterial({ color: 0x22d3ee, size: 0.008, transparent: true, opacity: 0.8 })));
    }
    // pprs6's base frame is z-up: turn it into three's y-up for viewing (the hook reads back platform in the
    // pprs6 base frame: see payloadPose, which uses the platform's matrix relative to this group).
    group.rotation.x = -Math.PI / 2;
    this.root.add(group);
    this.pprs6 = { group, chains, platform };
    this.showPprs6Frame(scene.frames, 0);
  }

  showPprs6Frame(frames, i) {
    if (!this.pprs6) return;
    const set = (mesh, a, b) => {
      const va = new THREE.Vector3(...a);
      const vb = new THREE.Vector3(...b);
      const d = vb.clone().sub(va);
      const len = d.length();
      mesh.position.copy(va.clone().add(vb).multiplyScalar(0.5));
      mesh.quaternion.setFromUnitVectors(new THREE.Vector3(0, 1, 0), d.normalize());
      mesh.scale.set(1, Math.max(len, 1e-6), 1);
    };
    for (let k = 0; k < 3; k++) {
      set(this.pprs6.chains[k].column, frames.B_m[i][k], frames.D_m[i][k]);
      set(this.pprs6.chains[k].link, frames.D_m[i][k], frames.C_m[i][k]);
    }
    const pose = frames.pose[i];
    this.pprs6.platform.matrix.copy(matrixOf(frames.platform_rotation[i], pose.slice(0, 3)));
    this.pprs6.platform.matrixWorldNeedsUpdate = true;
    this.render();
  }
}
