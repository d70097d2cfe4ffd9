// Pointer tools on the canvas: Move (drag the handle in the view plane), Brush and Lasso.
import * as THREE from "three";
import type { Viewer3D } from "./scene";
import { brushSelect, lassoSelect } from "./selection";

export type Tool = "move" | "brush" | "lasso";

export interface InteractionHost {
  tool(): Tool;
  canEdit(): boolean;
  positions(): Float32Array | null;
  handleVertices(): number[];
  /** World centroid of the handle as rendered. */
  handleCentroid(): THREE.Vector3 | null;
  /** Drag in the view plane: `delta` from the drag start, `t0` the pointer event time. */
  dragStart(): void;
  dragMove(delta: THREE.Vector3, t0: number): void;
  dragEnd(): void;
  paint(indices: number[]): void;
  brushRadius(): number;
}

const PICK_PX = 8;

export class Interaction {
  private drag: { plane: THREE.Plane; start: THREE.Vector3; id: number } | null = null;
  private painting = false;
  private lasso: number[] | null = null;

  constructor(private readonly viewer: () => Viewer3D | null, private readonly canvas: HTMLCanvasElement, private readonly host: InteractionHost, private readonly lassoLine: SVGPolylineElement) {}

  /** Registered before the orbit/gizmo controls so that we can claim the pointer first. */
  attach(): void {
    this.canvas.addEventListener("pointerdown", (e) => this.down(e));
    this.canvas.addEventListener("pointermove", (e) => this.move(e));
    this.canvas.addEventListener("pointerup", (e) => this.up(e));
    this.canvas.addEventListener("pointercancel", (e) => this.up(e));
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
    if (!v || e.button !== 0 || !this.host.canEdit()) return;
    const tool = this.host.tool();
    if (tool === "move") {
      if (v.gizmo.axis !== null && v.gizmo.enabled) return; // the gizmo takes it
      const start = this.handleGrab(v, e.clientX, e.clientY);
      if (!start) return;
      this.claim(e);
      this.drag = { plane: new THREE.Plane().setFromNormalAndCoplanarPoint(v.viewDirection(), start), start, id: e.pointerId };
      this.host.dragStart();
    } else if (tool === "brush") {
      this.claim(e);
      this.painting = true;
      this.brushAt(v, e.clientX, e.clientY);
    } else if (tool === "lasso") {
      this.claim(e);
      this.lasso = [e.clientX, e.clientY];
      this.drawLasso();
    }
  }

  private move(e: PointerEvent): void {
    const v = this.viewer();
    if (!v) return;
    const t0 = performance.now();
    if (this.drag && e.pointerId === this.drag.id) {
      e.stopImmediatePropagation();
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
    }
  }

  private up(e: PointerEvent): void {
    const v = this.viewer();
    if (this.drag) {
      this.drag = null;
      this.host.dragEnd();
    }
    this.painting = false;
    if (this.lasso && v) {
      const poly = this.lasso;
      this.lasso = null;
      this.drawLasso();
      this.host.paint(this.lassoPick(v, poly));
    }
    try {
      this.canvas.releasePointerCapture(e.pointerId);
    } catch {
      /* not captured */
    }
  }

  /** The world point to drag from if (x, y) is on or within a few pixels of the handle. */
  private handleGrab(v: Viewer3D, x: number, y: number): THREE.Vector3 | null {
    const p = this.host.positions();
    const hv = this.host.handleVertices();
    if (!p || hv.length === 0) return null;
    const c = this.host.handleCentroid();
    if (c) {
      const s = v.toScreen(c.x, c.y, c.z);
      if (s && Math.hypot(s[0] - x, s[1] - y) <= PICK_PX * 1.5) return c;
    }
    let best = -1, bestD = PICK_PX;
    const tmp = new THREE.Vector3();
    for (const i of hv) {
      const s = v.toScreen(p[i * 3], p[i * 3 + 1], p[i * 3 + 2], tmp);
      if (!s) continue;
      const d = Math.hypot(s[0] - x, s[1] - y);
      if (d < bestD) { bestD = d; best = i; }
    }
    if (best >= 0) return new THREE.Vector3(p[best * 3], p[best * 3 + 1], p[best * 3 + 2]);
    const hit = v.pick(x, y);
    if (hit?.face) {
      const set = new Set(hv);
      if (set.has(hit.face.a) || set.has(hit.face.b) || set.has(hit.face.c)) return hit.point.clone();
    }
    return null;
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
    return lassoSelect(
      p.length / 3,
      poly,
      (i) => v.toScreen(p[i * 3], p[i * 3 + 1], p[i * 3 + 2], tmp),
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
