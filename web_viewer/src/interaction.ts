// Pointer tools on the canvas: Move (drag any handle group in the view plane; a click selects the
// group under the pointer), Grab (issue 44: press on the mesh and drag: a handle forms around the
// point and the drag starts at once; the wheel over the mesh sets its radius), Brush and Lasso
// (each stroke is one paint stroke; Shift extends), and the pointer side of a modal transform
// (G / R / S: the pointer moves the group, a click confirms, a right-click cancels).
import * as THREE from "three";
import type { Viewer3D } from "./scene";
import { brushSelect, lassoSelect } from "./selection";

export type Tool = "move" | "grab" | "brush" | "lasso";

export interface HandleGroupView {
  /** Index into the applied groups. */
  index: number;
  vertices: number[];
  /** World centroid as rendered. */
  centroid: THREE.Vector3 | null;
}

export interface PickHit {
  point: THREE.Vector3;
  /** The vertices of the face under the pointer. */
  face: [number, number, number];
}

export interface InteractionHost {
  tool(): Tool;
  canEdit(): boolean;
  /** Handles can be dragged (the painted groups are applied, nothing else is under way). */
  canMove(): boolean;
  positions(): Float32Array | null;
  /** The applied handle groups; the selected one first, so it wins ties. */
  handleGroups(): HandleGroupView[];
  /** The group (any role) of a vertex, -1 for none. */
  groupOf(vertex: number): number;
  select(group: number): void;
  /** Drag in the view plane: `delta` from the drag start, `t0` the pointer event time. */
  dragStart(group: number): void;
  dragMove(delta: THREE.Vector3, t0: number): void;
  dragEnd(): void;
  /** Grab tool: a press on the mesh off every handle. Returns false to let the orbit have it. */
  pickStart(hit: PickHit): boolean;
  /** Grab tool: the pointer over the mesh (null: off it), for the radius preview. */
  hover(hit: PickHit | null): void;
  /** Grab tool: the wheel over the mesh (WheelEvent.deltaY: negative, up, grows it). */
  radiusWheel(deltaY: number): void;
  /** A modal transform (G / R / S) is open: the pointer drives it. */
  modalActive(): boolean;
  modalPointer(x: number, y: number): void;
  modalConfirm(): void;
  modalCancel(): void;
  /** A stroke: paintStart, paint (once per brush dab or once per lasso), paintEnd. */
  paintStart(extend: boolean): void;
  paint(indices: number[]): void;
  paintEnd(): void;
  brushRadius(): number;
  /** How long a pointer event waited before the page ran its handler (ms), during drags. */
  inputDelay(ms: number): void;
}

const PICK_PX = 8;

export class Interaction {
  private drag: { plane: THREE.Plane; start: THREE.Vector3; id: number } | null = null;
  private painting = false;
  private lasso: number[] | null = null;
  private lassoExtend = false;
  /** A press in Move mode that did not grab a handle: a click (no travel) selects. */
  private press: { x: number; y: number; id: number } | null = null;
  /** The last pointer position over the canvas (a modal transform starts from it). */
  lastPointer: { x: number; y: number } | null = null;
  private hoverQueued: { x: number; y: number } | null = null;
  private hoverHit: PickHit | null = null;

  /** A handle drag is under way. */
  get dragging(): boolean {
    return this.drag !== null;
  }

  constructor(private readonly viewer: () => Viewer3D | null, private readonly canvas: HTMLCanvasElement, private readonly host: InteractionHost, private readonly lassoLine: SVGPolylineElement) {}

  /** Registered before the orbit/gizmo controls so that we can claim the pointer first. */
  attach(): void {
    this.canvas.addEventListener("pointerdown", (e) => this.down(e));
    this.canvas.addEventListener("pointermove", (e) => this.move(e));
    this.canvas.addEventListener("pointerup", (e) => this.up(e));
    this.canvas.addEventListener("pointercancel", (e) => this.up(e));
    this.canvas.addEventListener("pointerleave", () => this.leave());
    this.canvas.addEventListener("wheel", (e) => this.wheel(e), { passive: false });
    this.canvas.addEventListener("contextmenu", (e) => {
      if (this.host.modalActive()) e.preventDefault();
    });
    // A modal transform follows the pointer also off the canvas.
    window.addEventListener("pointermove", (e) => {
      if (e.target !== this.canvas && this.host.modalActive()) this.host.modalPointer(e.clientX, e.clientY);
    });
  }

  private claim(e: PointerEvent): void {
    e.stopImmediatePropagation();
    e.preventDefault();
    try {
      this.canvas.setPointerCapture(e.pointerId);
    } catch {
      /* synthetic events have no capturable pointer */
    }
  }

  private down(e: PointerEvent): void {
    const v = this.viewer();
    if (!v || !this.host.canEdit()) return;
    if (this.host.modalActive()) {
      // Left confirms, right cancels (Blender); neither orbits.
      e.stopImmediatePropagation();
      e.preventDefault();
      if (e.button === 0) this.host.modalConfirm();
      else if (e.button === 2) this.host.modalCancel();
      return;
    }
    if (e.button !== 0) return;
    const tool = this.host.tool();
    if (tool === "move" || tool === "grab") {
      if (v.gizmo.axis !== null && v.gizmo.enabled) return; // the gizmo takes it
      const grab = this.host.canMove() ? this.handleGrab(v, e.clientX, e.clientY) : null;
      if (grab) {
        this.claim(e);
        this.host.select(grab.group);
        this.startDrag(v, grab.start, e.pointerId);
        this.host.dragStart(grab.group);
        return;
      }
      if (tool === "grab" && this.host.canMove()) {
        const hit = this.pickAt(v, e.clientX, e.clientY);
        if (hit && this.host.pickStart(hit)) {
          this.claim(e);
          this.startDrag(v, hit.point.clone(), e.pointerId);
          return;
        }
      }
      this.press = { x: e.clientX, y: e.clientY, id: e.pointerId }; // orbit goes on; maybe a click
    } else if (tool === "brush") {
      this.claim(e);
      this.painting = true;
      this.host.paintStart(e.shiftKey);
      this.brushAt(v, e.clientX, e.clientY);
    } else if (tool === "lasso") {
      this.claim(e);
      this.lasso = [e.clientX, e.clientY];
      this.lassoExtend = e.shiftKey;
      this.drawLasso();
    }
  }

  private startDrag(v: Viewer3D, start: THREE.Vector3, id: number): void {
    this.drag = { plane: new THREE.Plane().setFromNormalAndCoplanarPoint(v.viewDirection(), start), start, id };
  }

  private move(e: PointerEvent): void {
    const v = this.viewer();
    if (!v) return;
    const t0 = performance.now();
    this.lastPointer = { x: e.clientX, y: e.clientY };
    if (this.host.modalActive()) {
      e.stopImmediatePropagation();
      this.host.modalPointer(e.clientX, e.clientY);
      return;
    }
    // A drag of the gizmo (TransformControls' own listener moves the group): its input delay
    // counts as a drag's too.
    if (v.gizmo.dragging && !this.drag) this.host.inputDelay(Math.max(0, t0 - e.timeStamp));
    if (this.drag && e.pointerId === this.drag.id) {
      e.stopImmediatePropagation();
      // e.timeStamp and performance.now() share the page's clock.
      this.host.inputDelay(Math.max(0, t0 - e.timeStamp));
      const hit = v.ray(e.clientX, e.clientY).intersectPlane(this.drag.plane, new THREE.Vector3());
      if (hit) this.host.dragMove(hit.sub(this.drag.start), t0);
    } else if (this.painting) {
      e.stopImmediatePropagation();
      this.brushAt(v, e.clientX, e.clientY);
    } else if (this.lasso) {
      e.stopImmediatePropagation();
      const n = this.lasso.length;
      if (Math.hypot(e.clientX - this.lasso[n - 2], e.clientY - this.lasso[n - 1]) > 3) {
        this.lasso.push(e.clientX, e.clientY);
        this.drawLasso();
      }
    } else if (this.host.tool() === "grab" && e.buttons === 0) {
      this.queueHover(e.clientX, e.clientY);
    }
  }

  /** The radius preview follows the pointer, one pick per animation frame at most (a pick of a
   * 187k-vertex mesh takes milliseconds). */
  private queueHover(x: number, y: number): void {
    const first = this.hoverQueued === null;
    this.hoverQueued = { x, y };
    if (!first) return;
    requestAnimationFrame(() => {
      const q = this.hoverQueued;
      this.hoverQueued = null;
      const v = this.viewer();
      if (!q || !v || this.host.tool() !== "grab" || this.drag) return;
      this.hoverHit = this.pickAt(v, q.x, q.y);
      this.host.hover(this.hoverHit);
    });
  }

  private leave(): void {
    if (this.drag || this.host.tool() !== "grab") return;
    this.hoverHit = null;
    this.host.hover(null);
  }

  private wheel(e: WheelEvent): void {
    // Grab tool, over the mesh: the wheel sets the radius (Ctrl + wheel, or the wheel off the
    // mesh, still zooms).
    if (this.host.tool() !== "grab" || e.ctrlKey || !this.hoverHit || this.drag) return;
    e.stopImmediatePropagation();
    e.preventDefault();
    this.host.radiusWheel(e.deltaY);
  }

  private up(e: PointerEvent): void {
    const v = this.viewer();
    if (this.drag) {
      this.drag = null;
      this.host.dragEnd();
    }
    if (this.painting) {
      this.painting = false;
      this.host.paintEnd();
    }
    if (this.lasso && v) {
      const poly = this.lasso;
      this.lasso = null;
      this.drawLasso();
      this.host.paintStart(this.lassoExtend);
      this.host.paint(this.lassoPick(v, poly));
      this.host.paintEnd();
    }
    const press = this.press;
    this.press = null;
    if (press && v && press.id === e.pointerId && Math.hypot(e.clientX - press.x, e.clientY - press.y) <= 4) {
      this.host.select(this.groupAt(v, e.clientX, e.clientY));
    }
    try {
      this.canvas.releasePointerCapture(e.pointerId);
    } catch {
      /* not captured */
    }
  }

  /** The surface point and face under (x, y), or null. */
  pickAt(v: Viewer3D, x: number, y: number): PickHit | null {
    const hit = v.pick(x, y);
    if (!hit?.face) return null;
    return { point: hit.point.clone(), face: [hit.face.a, hit.face.b, hit.face.c] };
  }

  /** The handle group and world point to drag from if (x, y) is on or within a few pixels of a
   * handle group: its centre marker first, then its nearest vertex, then a face it touches. */
  private handleGrab(v: Viewer3D, x: number, y: number): { group: number; start: THREE.Vector3 } | null {
    const p = this.host.positions();
    const groups = this.host.handleGroups();
    if (!p || groups.length === 0) return null;
    let best: { group: number; start: THREE.Vector3; d: number } | null = null;
    const r = this.canvas.getBoundingClientRect();
    for (const g of groups) {
      const c = g.centroid;
      const s = c && v.toScreen(c.x, c.y, c.z, undefined, r);
      const d = s ? Math.hypot(s[0] - x, s[1] - y) : Infinity;
      if (c && d <= PICK_PX * 1.5 && (!best || d < best.d)) best = { group: g.index, start: c.clone(), d };
    }
    if (best) return best;
    let bestV = -1, bestG = -1, bestD = PICK_PX;
    const tmp = new THREE.Vector3();
    for (const g of groups) {
      for (const i of g.vertices) {
        const s = v.toScreen(p[i * 3], p[i * 3 + 1], p[i * 3 + 2], tmp, r);
        if (!s) continue;
        const d = Math.hypot(s[0] - x, s[1] - y);
        if (d < bestD) { bestD = d; bestV = i; bestG = g.index; }
      }
    }
    if (bestV >= 0) return { group: bestG, start: new THREE.Vector3(p[bestV * 3], p[bestV * 3 + 1], p[bestV * 3 + 2]) };
    const hit = v.pick(x, y);
    if (hit?.face) {
      for (const g of groups) {
        const set = new Set(g.vertices);
        if (set.has(hit.face.a) || set.has(hit.face.b) || set.has(hit.face.c)) return { group: g.index, start: hit.point.clone() };
      }
    }
    return null;
  }

  /** The group (any role) of the vertex nearest to the surface point under (x, y), -1 if none. */
  private groupAt(v: Viewer3D, x: number, y: number): number {
    const hit = v.pick(x, y);
    const p = this.host.positions();
    if (!hit?.face || !p) return -1;
    let best = -1, bestD = Infinity;
    for (const i of [hit.face.a, hit.face.b, hit.face.c]) {
      const d = hit.point.distanceToSquared(new THREE.Vector3(p[i * 3], p[i * 3 + 1], p[i * 3 + 2]));
      if (d < bestD) { bestD = d; best = i; }
    }
    return best >= 0 ? this.host.groupOf(best) : -1;
  }

  private brushAt(v: Viewer3D, x: number, y: number): void {
    const hit = v.pick(x, y);
    const p = this.host.positions();
    if (!hit || !p) return;
    this.host.paint(brushSelect(p, [hit.point.x, hit.point.y, hit.point.z], this.host.brushRadius()));
  }

  private lassoPick(v: Viewer3D, poly: number[]): number[] {
    const p = this.host.positions();
    const g = v.geometry;
    if (!p || !g || poly.length < 6) return [];
    const normals = g.getAttribute("normal").array as Float32Array;
    const cam = v.camera.position;
    const tmp = new THREE.Vector3();
    const r = this.canvas.getBoundingClientRect();
    return lassoSelect(
      p.length / 3,
      poly,
      (i) => v.toScreen(p[i * 3], p[i * 3 + 1], p[i * 3 + 2], tmp, r),
      (i) =>
        normals[i * 3] * (cam.x - p[i * 3]) + normals[i * 3 + 1] * (cam.y - p[i * 3 + 1]) + normals[i * 3 + 2] * (cam.z - p[i * 3 + 2]) > 0,
    );
  }

  private drawLasso(): void {
    const r = this.canvas.getBoundingClientRect();
    const pts: string[] = [];
    const l = this.lasso ?? [];
    for (let i = 0; i < l.length; i += 2) pts.push(`${l[i] - r.left},${l[i + 1] - r.top}`);
    if (pts.length) pts.push(pts[0]);
    this.lassoLine.setAttribute("points", pts.join(" "));
  }
}
