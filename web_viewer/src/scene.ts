// three.js scene: the deformable mesh, camera + orbit controls, the handle gizmo, and an
// on-demand render loop that can tell callers when the frame showing their geometry is done.
import * as THREE from "three";
import { OrbitControls } from "three/addons/controls/OrbitControls.js";
import { TransformControls } from "three/addons/controls/TransformControls.js";
import type { CoarseFrame } from "./coarse";
import { vertexNormals } from "./geometry";
import { defaultView, namedView, type ViewDir, type ViewName } from "./views";

export class Viewer3D {
  readonly renderer: THREE.WebGLRenderer;
  readonly scene = new THREE.Scene();
  readonly camera = new THREE.PerspectiveCamera(40, 1, 0.01, 1000);
  readonly orbit: OrbitControls;
  readonly gizmo: TransformControls;
  /** The gizmo's target: at the handle centroid, carries the group's rotation and scale. */
  readonly pivotObject = new THREE.Object3D();
  geometry: THREE.BufferGeometry | null = null;
  mesh: THREE.Mesh | null = null;
  /** Edges drawn over the surface (shares the geometry, so it follows every update). */
  private wire: THREE.Mesh | null = null;
  private wireOn = false;
  /** The rest pose, translucent. */
  private ghost: THREE.Mesh | null = null;
  private ghostOn = false;
  /** One sphere per handle group at its centre (the selected one carries the gizmo). */
  private readonly markers = new THREE.Group();
  /** Where the pending move puts the handle vertices, while a slow solve runs. */
  private targets: THREE.Points | null = null;
  /** Grab tool: the sphere a press would take as the handle. */
  private readonly grabPreview = new THREE.Mesh(
    new THREE.SphereGeometry(1, 24, 16),
    new THREE.MeshBasicMaterial({ color: 0xf58024, transparent: true, opacity: 0.28, depthWrite: false }),
  );
  /** The coarse level of a multiresolution drag (src/coarse.ts): drawn instead of the mesh
   * while shown (setCoarseFrame until showFull), coloured as the mesh at its vertices. */
  private coarse: { key: string; mesh: THREE.Mesh; toFine: Uint32Array } | null = null;
  private coarseShown = false;
  private pendingCoarse: CoarseFrame | null = null;
  private coarseColorsStale = false;
  private frameQueued = false;
  private afterFrame: (() => void)[] = [];
  /** Milliseconds each frame spent on normals + drawing (bench: is the browser the bottleneck?). */
  readonly frameWorkMs: number[] = [];
  private readonly raycaster = new THREE.Raycaster();

  constructor(readonly canvas: HTMLCanvasElement, beforeControls: () => void) {
    // Multisampling on a software rasterizer (SwiftShader, llvmpipe: no GPU) costs a large part of
    // every frame and slows down input while dragging; real GPUs get it.
    this.renderer = new THREE.WebGLRenderer({ canvas, antialias: !isSoftwareRenderer() });
    this.renderer.setPixelRatio(Math.min(window.devicePixelRatio, 2));
    this.renderer.setClearColor(0xf4f6f9);
    this.scene.add(new THREE.HemisphereLight(0xffffff, 0x6b7385, 1.1));
    const key = new THREE.DirectionalLight(0xffffff, 1.3);
    key.position.set(0.5, 1, 0.8);
    this.camera.add(key); // a headlight-ish key light that follows the view
    this.scene.add(this.camera);
    // Our pointer handlers must see pointerdown before the controls so a drag on the handle
    // can stop the orbit from starting.
    beforeControls();
    this.orbit = new OrbitControls(this.camera, canvas);
    this.orbit.enableDamping = false;
    this.orbit.addEventListener("change", () => this.requestRender());
    this.gizmo = new TransformControls(this.camera, canvas);
    this.gizmo.setSize(0.8);
    this.gizmo.addEventListener("change", () => this.requestRender());
    this.gizmo.addEventListener("dragging-changed", (e: any) => (this.orbit.enabled = !e.value));
    this.scene.add(this.pivotObject);
    this.scene.add(this.markers);
    this.scene.add(this.gizmo.getHelper());
    this.grabPreview.visible = false;
    this.grabPreview.renderOrder = 3;
    this.scene.add(this.grabPreview);
    new ResizeObserver(() => this.resize()).observe(canvas);
    this.resize();
  }

  resize(): void {
    const w = Math.max(1, this.canvas.clientWidth), h = Math.max(1, this.canvas.clientHeight);
    this.renderer.setSize(w, h, false);
    this.camera.aspect = w / h;
    this.camera.updateProjectionMatrix();
    this.requestRender();
  }

  setMesh(positions: Float32Array, indices: Uint32Array): void {
    if (this.mesh) {
      this.scene.remove(this.mesh);
      this.geometry?.dispose();
    }
    this.dropCoarse();
    for (const o of [this.wire, this.ghost, this.targets]) if (o) { this.scene.remove(o); if (o !== this.wire) o.geometry.dispose(); }
    this.wire = this.ghost = this.targets = null;
    const g = new THREE.BufferGeometry();
    const pos = new THREE.BufferAttribute(Float32Array.from(positions), 3);
    pos.setUsage(THREE.DynamicDrawUsage);
    g.setAttribute("position", pos);
    const col = new THREE.BufferAttribute(new Float32Array(positions.length).fill(0.8), 3);
    col.setUsage(THREE.DynamicDrawUsage);
    g.setAttribute("color", col);
    g.setIndex(new THREE.BufferAttribute(indices, 1));
    g.computeVertexNormals();
    (g.getAttribute("normal") as THREE.BufferAttribute).setUsage(THREE.DynamicDrawUsage);
    g.computeBoundingSphere();
    g.computeBoundingBox();
    // Pushed back a little so that the wireframe overlay draws on top without z-fighting.
    const mat = new THREE.MeshStandardMaterial({ vertexColors: true, roughness: 0.65, metalness: 0.0, side: THREE.DoubleSide, polygonOffset: true, polygonOffsetFactor: 1, polygonOffsetUnits: 1 });
    this.geometry = g;
    this.mesh = new THREE.Mesh(g, mat);
    this.scene.add(this.mesh);
    this.wire = new THREE.Mesh(g, new THREE.MeshBasicMaterial({ color: 0x1d2430, wireframe: true, transparent: true, opacity: 0.35 }));
    this.wire.visible = this.wireOn;
    this.scene.add(this.wire);
    const size = g.boundingBox!.getSize(new THREE.Vector3());
    this.homeView = defaultView([size.x, size.y, size.z]);
    this.frame();
  }

  /** The view a mesh opens with (views.ts: across its longest axis); Frame returns to it. */
  private homeView: ViewDir = { eye: [0.6, 0.45, 1], up: [0, 1, 0] };

  /** Front / side / top (or their opposites), framing the mesh. */
  setView(name: ViewName): void {
    this.frame(namedView(name));
  }

  /** Grab tool: shows the sphere of `radius` about `center` (null hides it). */
  setGrabPreview(center: THREE.Vector3 | null, radius: number): void {
    this.grabPreview.visible = !!center;
    if (center) {
      this.grabPreview.position.copy(center);
      this.grabPreview.scale.setScalar(Math.max(radius, 1e-9));
    }
    this.requestRender();
  }

  setWireframe(on: boolean): void {
    this.wireOn = on;
    if (this.wire) this.wire.visible = on && !this.coarseShown;
    this.requestRender();
  }

  /** The rest pose as a translucent ghost (`rest` is copied once per mesh). */
  setGhost(on: boolean, rest: Float32Array | null): void {
    this.ghostOn = on;
    if (on && !this.ghost && rest && this.geometry) {
      const g = new THREE.BufferGeometry();
      g.setAttribute("position", new THREE.BufferAttribute(Float32Array.from(rest), 3));
      g.setIndex(this.geometry.getIndex());
      const m = new THREE.MeshBasicMaterial({ color: 0x4a6fb5, transparent: true, opacity: 0.22, depthWrite: false, side: THREE.DoubleSide });
      this.ghost = new THREE.Mesh(g, m);
      this.ghost.renderOrder = 2;
      this.scene.add(this.ghost);
    }
    if (this.ghost) this.ghost.visible = this.ghostOn;
    this.requestRender();
  }

  /** Sphere markers at the handle groups' centres. */
  setMarkers(items: { at: [number, number, number]; color: [number, number, number]; selected: boolean }[]): void {
    const bb = this.geometry?.boundingBox;
    const r = (bb ? bb.getSize(new THREE.Vector3()).length() : 1) * 0.012;
    while (this.markers.children.length > items.length) {
      const m = this.markers.children.pop() as THREE.Mesh;
      m.geometry.dispose();
      (m.material as THREE.Material).dispose();
    }
    while (this.markers.children.length < items.length) {
      const m = new THREE.Mesh(new THREE.SphereGeometry(1, 16, 12), new THREE.MeshBasicMaterial({ depthTest: false, transparent: true, opacity: 0.9 }));
      m.renderOrder = 5;
      this.markers.add(m);
    }
    items.forEach((it, i) => {
      const m = this.markers.children[i] as THREE.Mesh;
      m.position.set(...it.at);
      m.scale.setScalar(it.selected ? r * 0.6 : r);
      (m.material as THREE.MeshBasicMaterial).color.setRGB(...it.color, THREE.SRGBColorSpace);
    });
    this.requestRender();
  }

  /** Points at the pending targets; null hides them. */
  setTargets(points: Float32Array | null): void {
    if (!points || points.length === 0) {
      if (this.targets) this.targets.visible = false;
      this.requestRender();
      return;
    }
    if (!this.targets || (this.targets.geometry.getAttribute("position") as THREE.BufferAttribute).array.length !== points.length) {
      if (this.targets) { this.scene.remove(this.targets); this.targets.geometry.dispose(); }
      const g = new THREE.BufferGeometry();
      g.setAttribute("position", new THREE.BufferAttribute(new Float32Array(points.length), 3));
      this.targets = new THREE.Points(g, new THREE.PointsMaterial({ color: 0xb34700, size: 3, sizeAttenuation: false, depthTest: false, transparent: true, opacity: 0.7 }));
      this.targets.renderOrder = 4;
      this.scene.add(this.targets);
    }
    const attr = this.targets.geometry.getAttribute("position") as THREE.BufferAttribute;
    (attr.array as Float32Array).set(points);
    attr.needsUpdate = true;
    this.targets.geometry.computeBoundingSphere();
    this.targets.visible = true;
    this.requestRender();
  }

  /** Frames the camera on the mesh bounding box, from `view` (default: the mesh's home view). */
  frame(view: ViewDir = this.homeView): void {
    const bb = this.geometry?.boundingBox;
    if (!bb) return;
    const c = bb.getCenter(new THREE.Vector3());
    const r = Math.max(1e-6, bb.getSize(new THREE.Vector3()).length() / 2);
    const fov = Math.min(this.camera.fov, this.camera.fov * this.camera.aspect);
    const dist = r / Math.sin(THREE.MathUtils.degToRad(fov / 2)) * 1.05;
    this.camera.position.copy(c).add(new THREE.Vector3(...view.eye).normalize().multiplyScalar(dist));
    this.camera.near = dist / 100;
    this.camera.far = dist * 100;
    this.camera.updateProjectionMatrix();
    this.orbit.target.copy(c);
    this.orbit.update();
    this.requestRender();
  }

  /** New positions with their normals and bounding sphere (made off the main thread, see
   * frames.ts): uploaded at the next animation frame, the newest only. */
  setFrame(positions: Float32Array, normals: Float32Array, sphere: { center: [number, number, number]; radius: number }): void {
    if (!this.geometry) return;
    this.pendingCoarse = null;
    this.pendingFrame = { positions, normals, sphere };
    this.requestRender();
  }

  /** Takes the coarse level's mesh when the frame brings one (always: the worker sends it once)
   * and, with `show`, draws the level instead of the full mesh from this frame on until
   * showFull. False (nothing drawn) without `show` or when the frame's level is not the one
   * whose mesh came last. */
  setCoarseFrame(f: CoarseFrame, show: boolean): boolean {
    if (!this.geometry) return false;
    if (f.mesh) {
      this.dropCoarse();
      const g = new THREE.BufferGeometry();
      for (const name of ["position", "normal", "color"]) {
        const a = new THREE.BufferAttribute(new Float32Array(f.positions.length), 3);
        a.setUsage(THREE.DynamicDrawUsage);
        g.setAttribute(name, a);
      }
      g.setIndex(new THREE.BufferAttribute(f.mesh.indices, 1));
      const mesh = new THREE.Mesh(g, this.mesh!.material);
      mesh.visible = false;
      this.scene.add(mesh);
      this.coarse = { key: f.key, mesh, toFine: f.mesh.toFine };
    }
    if (!show || !this.coarse || this.coarse.key !== f.key || f.positions.length !== 3 * this.coarse.toFine.length) return false;
    this.pendingCoarse = f;
    this.coarseColorsStale = true;
    this.requestRender();
    return true;
  }

  /** Back to the full mesh at `positions` (its normals computed here), if the coarse level is
   * shown or about to be. */
  showFull(positions: Float32Array): void {
    const had = this.coarsePending;
    this.pendingCoarse = null;
    if (!had || !this.geometry || !this.mesh) return;
    this.drawCoarse(false);
    this.pendingFrame = null;
    const g = this.geometry;
    const attr = g.getAttribute("position") as THREE.BufferAttribute;
    if ((attr.array as Float32Array).length === positions.length) {
      (attr.array as Float32Array).set(positions);
      attr.needsUpdate = true;
      const normals = g.getAttribute("normal") as THREE.BufferAttribute;
      vertexNormals(positions, g.getIndex()!.array, normals.array as Float32Array);
      normals.needsUpdate = true;
      g.computeBoundingSphere();
    }
    this.requestRender();
  }

  /** Whether the coarse level is drawn, and how many vertices the drawn mesh has (tests). */
  get showingCoarse(): boolean {
    return this.coarseShown;
  }
  /** The coarse level is drawn or will be at the next frame. */
  get coarsePending(): boolean {
    return this.coarseShown || this.pendingCoarse !== null;
  }
  drawnVertexCount(): number {
    const g = this.coarseShown ? this.coarse?.mesh.geometry : this.geometry;
    return g ? g.getAttribute("position").count : 0;
  }

  /** Draws the coarse level (on) or the full mesh with its wireframe, if on (off). */
  private drawCoarse(on: boolean): void {
    this.coarseShown = on;
    if (this.mesh) this.mesh.visible = !on;
    if (this.wire) this.wire.visible = this.wireOn && !on;
    if (this.coarse) this.coarse.mesh.visible = on;
  }

  private dropCoarse(): void {
    if (this.coarseShown) this.drawCoarse(false);
    if (this.coarse) {
      this.scene.remove(this.coarse.mesh);
      this.coarse.mesh.geometry.dispose();
    }
    this.coarse = null;
    this.pendingCoarse = null;
  }

  private flushCoarse(): void {
    const c = this.coarse, f = this.pendingCoarse;
    this.pendingCoarse = null;
    if (!c || !this.mesh) return;
    const g = c.mesh.geometry;
    if (f) {
      const pos = g.getAttribute("position") as THREE.BufferAttribute;
      (pos.array as Float32Array).set(f.positions);
      pos.needsUpdate = true;
      const nrm = g.getAttribute("normal") as THREE.BufferAttribute;
      (nrm.array as Float32Array).set(f.normals);
      nrm.needsUpdate = true;
      g.computeBoundingSphere();
      this.drawCoarse(true);
    }
    const full = this.colorArray();
    if (this.coarseShown && this.coarseColorsStale && full) {
      const col = g.getAttribute("color") as THREE.BufferAttribute;
      const dst = col.array as Float32Array;
      for (let i = 0; i < c.toFine.length; i++) {
        const v = c.toFine[i] * 3;
        dst[3 * i] = full[v];
        dst[3 * i + 1] = full[v + 1];
        dst[3 * i + 2] = full[v + 2];
      }
      col.needsUpdate = true;
      this.coarseColorsStale = false;
    }
  }

  private pendingFrame: { positions: Float32Array; normals: Float32Array; sphere: { center: [number, number, number]; radius: number } } | null = null;

  private flushPositions(): void {
    const g = this.geometry;
    const f = this.pendingFrame;
    this.pendingFrame = null;
    if (!g || !f) return;
    const attr = g.getAttribute("position") as THREE.BufferAttribute;
    if ((attr.array as Float32Array).length !== f.positions.length) return;
    if (this.coarseShown) this.drawCoarse(false);  // a full frame ends the coarse level's drawing
    (attr.array as Float32Array).set(f.positions);
    attr.needsUpdate = true;
    const normals = g.getAttribute("normal") as THREE.BufferAttribute;
    (normals.array as Float32Array).set(f.normals);
    normals.needsUpdate = true;
    g.boundingSphere ??= new THREE.Sphere();
    g.boundingSphere.center.set(...f.sphere.center);
    g.boundingSphere.radius = f.sphere.radius;
  }

  /** The vertex colour array (linear RGB) to fill in place; call colorsChanged() after. */
  colorArray(): Float32Array | null {
    const attr = this.geometry?.getAttribute("color") as THREE.BufferAttribute | undefined;
    return attr ? (attr.array as Float32Array) : null;
  }

  colorsChanged(): void {
    const attr = this.geometry?.getAttribute("color") as THREE.BufferAttribute | undefined;
    if (attr) attr.needsUpdate = true;
    this.coarseColorsStale = true;
    this.requestRender();
  }

  /** Per-vertex sRGB colours; stored linear, as three's vertex colours are. */
  setColors(rgb: Float32Array): void {
    const attr = this.geometry?.getAttribute("color") as THREE.BufferAttribute | undefined;
    if (!attr) return;
    const dst = attr.array as Float32Array;
    for (let i = 0; i < rgb.length; i++) dst[i] = srgbToLinear(rgb[i]);
    attr.needsUpdate = true;
    this.coarseColorsStale = true;
    this.requestRender();
  }

  requestRender(): void {
    if (this.frameQueued) return;
    this.frameQueued = true;
    requestAnimationFrame(() => {
      this.frameQueued = false;
      const start = performance.now();
      this.flushPositions();
      this.flushCoarse();
      this.renderer.render(this.scene, this.camera);
      if (this.frameWorkMs.length < 10_000) this.frameWorkMs.push(performance.now() - start);
      const cbs = this.afterFrame;
      this.afterFrame = [];
      cbs.forEach((f) => f());
    });
  }

  /** Runs `cb` at the end of the next rendered frame (and makes sure there is one). */
  onNextFrame(cb: () => void): void {
    this.afterFrame.push(cb);
    this.requestRender();
  }

  /** Page CSS pixels of a world point, or null if it is behind the camera. Pass the canvas's
   * rectangle when projecting many points (reading it forces a layout). */
  toScreen(x: number, y: number, z: number, out = new THREE.Vector3(), r: DOMRect = this.canvas.getBoundingClientRect()): [number, number] | null {
    out.set(x, y, z).project(this.camera);
    if (out.z > 1 || out.z < -1) return null;
    return [r.left + ((out.x + 1) / 2) * r.width, r.top + ((1 - out.y) / 2) * r.height];
  }

  /** A ray through page CSS pixel (x, y). */
  ray(clientX: number, clientY: number): THREE.Ray {
    const r = this.canvas.getBoundingClientRect();
    const ndc = new THREE.Vector2(((clientX - r.left) / r.width) * 2 - 1, -((clientY - r.top) / r.height) * 2 + 1);
    this.raycaster.setFromCamera(ndc, this.camera);
    return this.raycaster.ray.clone();
  }

  pick(clientX: number, clientY: number): THREE.Intersection | null {
    if (!this.mesh) return null;
    this.ray(clientX, clientY);
    const hits = this.raycaster.intersectObject(this.mesh, false);
    return hits[0] ?? null;
  }

  viewDirection(): THREE.Vector3 {
    return this.camera.getWorldDirection(new THREE.Vector3());
  }
}

export function srgbToLinear(c: number): number {
  return c < 0.04045 ? c * 0.0773993808 : Math.pow(c * 0.9478672986 + 0.0521327014, 2.4);
}

/** True when WebGL runs on a CPU rasterizer (probed on a throwaway canvas). */
function isSoftwareRenderer(): boolean {
  try {
    const gl = document.createElement("canvas").getContext("webgl2") ?? document.createElement("canvas").getContext("webgl");
    if (!gl) return false;
    const info = gl.getExtension("WEBGL_debug_renderer_info");
    const name = String(info ? gl.getParameter(info.UNMASKED_RENDERER_WEBGL) : gl.getParameter(gl.RENDERER));
    gl.getExtension("WEBGL_lose_context")?.loseContext();
    return /swiftshader|llvmpipe|software/i.test(name);
  } catch {
    return false;
  }
}
