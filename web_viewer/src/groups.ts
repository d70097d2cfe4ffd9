// The handle groups being painted: each vertex is in at most one group; a group is fixed or a
// handle. A brush or lasso stroke starts a new group, or extends the selected one (Shift, or the
// "add to selected" mode) when that group has the painted role. Groups that lose every vertex are
// dropped; indices are kept compact so that they match the order sent to SetHandles.

export type GroupRole = "fixed" | "handle";

export interface GroupSpec {
  role: GroupRole;
  vertices: number[]; // ascending
}

export class GroupSet {
  private owner: Int32Array;
  private roleList: GroupRole[] = [];
  private counts: number[] = [];
  /** Index of the selected group, -1 for none. */
  selected = -1;
  private stroke: { role: GroupRole; extend: boolean; target: number } | null = null;

  constructor(readonly vertexCount: number, groups: GroupSpec[] = []) {
    this.owner = new Int32Array(vertexCount).fill(-1);
    for (const g of groups) {
      const k = this.roleList.length;
      this.roleList.push(g.role);
      this.counts.push(0);
      for (const v of g.vertices) this.assign(v, k);
    }
    this.compact();
  }

  get size(): number {
    return this.roleList.length;
  }

  role(i: number): GroupRole {
    return this.roleList[i];
  }

  /** Every group's role, in order. */
  roles(): GroupRole[] {
    return [...this.roleList];
  }

  count(i: number): number {
    return this.counts[i];
  }

  /** The group of vertex `v`, -1 if none. */
  groupOf(v: number): number {
    return this.owner[v];
  }

  vertices(i: number): number[] {
    const out: number[] = [];
    for (let v = 0; v < this.vertexCount; v++) if (this.owner[v] === i) out.push(v);
    return out;
  }

  /** Ordinal of group i among the groups of its role (colour and label: "Handle 2"). */
  ordinal(i: number): number {
    let k = 0;
    for (let j = 0; j < i; j++) if (this.roleList[j] === this.roleList[i]) k++;
    return k;
  }

  select(i: number): void {
    this.selected = i >= 0 && i < this.size ? i : -1;
  }

  /** Starts a stroke painting `role`; `extend` adds to the selected group if it has that role. */
  beginStroke(role: GroupRole, extend: boolean): void {
    this.stroke = { role, extend, target: -1 };
  }

  /** Adds vertices to the current stroke's group (created on the first non-empty call). */
  paint(indices: Iterable<number>): void {
    const st = this.stroke;
    if (!st) throw new Error("paint outside a stroke");
    let any = false;
    for (const v of indices) {
      if (st.target < 0) {
        const sel = this.selected;
        if (st.extend && sel >= 0 && this.roleList[sel] === st.role) st.target = sel;
        else {
          st.target = this.roleList.length;
          this.roleList.push(st.role);
          this.counts.push(0);
        }
      }
      this.assign(v, st.target);
      any = true;
    }
    if (!any) return;
    this.selected = st.target;
    this.compact();
  }

  endStroke(): void {
    this.stroke = null;
  }

  erase(indices: Iterable<number>): void {
    for (const v of indices) this.assign(v, -1);
    this.compact();
  }

  delete(i: number): void {
    if (i < 0 || i >= this.size) return;
    for (let v = 0; v < this.vertexCount; v++) if (this.owner[v] === i) this.assign(v, -1);
    this.compact();
  }

  clear(): void {
    this.owner.fill(-1);
    this.roleList = [];
    this.counts = [];
    this.selected = -1;
    if (this.stroke) this.stroke.target = -1;
  }

  specs(): GroupSpec[] {
    const lists: number[][] = this.roleList.map(() => []);
    for (let v = 0; v < this.vertexCount; v++) if (this.owner[v] >= 0) lists[this.owner[v]].push(v);
    return this.roleList.map((role, i) => ({ role, vertices: lists[i] }));
  }

  /** True when the groups are exactly `other` (same order, roles and vertices). */
  equals(other: GroupSpec[]): boolean {
    const mine = this.specs();
    return mine.length === other.length && mine.every((g, i) => g.role === other[i].role && sameList(g.vertices, other[i].vertices));
  }

  /** null when the groups can become handles, else what to do. */
  validate(): string | null {
    if (this.size === 0) return "Nothing painted yet: paint a fixed region and a handle, then Apply.";
    const handles = this.roleList.filter((r) => r === "handle").length;
    if (handles === 0) return "No handle group: paint one in mode “handle”.";
    if (handles === 1 && this.roleList.length === 1) return "No fixed region: paint one in mode “fixed” (or a second handle group).";
    return null;
  }

  private assign(v: number, k: number): void {
    const old = this.owner[v];
    if (old === k) return;
    if (old >= 0) this.counts[old]--;
    if (k >= 0) this.counts[k]++;
    this.owner[v] = k;
  }

  /** Drops empty groups, renumbering the rest (and the selection and stroke target). */
  private compact(): void {
    if (this.counts.every((c) => c > 0)) return;
    const map: number[] = [];
    const roles: GroupRole[] = [];
    const counts: number[] = [];
    this.counts.forEach((c, i) => {
      map.push(c > 0 ? roles.length : -1);
      if (c > 0) { roles.push(this.roleList[i]); counts.push(c); }
    });
    for (let v = 0; v < this.vertexCount; v++) if (this.owner[v] >= 0) this.owner[v] = map[this.owner[v]];
    this.roleList = roles;
    this.counts = counts;
    this.selected = this.selected >= 0 ? map[this.selected] ?? -1 : -1;
    if (this.stroke && this.stroke.target >= 0) this.stroke.target = map[this.stroke.target] ?? -1;
  }
}

function sameList(a: number[], b: ArrayLike<number>): boolean {
  if (a.length !== b.length) return false;
  for (let i = 0; i < a.length; i++) if (a[i] !== b[i]) return false;
  return true;
}

/** Colours (sRGB 0..1): fixed groups blue, handle groups from a palette starting with orange. */
export const FIXED_COLOR: [number, number, number] = [0.22, 0.42, 0.88];
export const HANDLE_COLORS: [number, number, number][] = [
  [0.96, 0.5, 0.14], // orange
  [0.84, 0.27, 0.6], // magenta
  [0.56, 0.36, 0.85], // purple
  [0.85, 0.69, 0.12], // ochre
  [0.75, 0.22, 0.17], // red
  [0.1, 0.62, 0.62], // teal
];

export function groupColor(role: GroupRole, ordinal: number): [number, number, number] {
  return role === "fixed" ? FIXED_COLOR : HANDLE_COLORS[ordinal % HANDLE_COLORS.length];
}

export function cssColor(c: [number, number, number]): string {
  return `rgb(${c.map((x) => Math.round(x * 255)).join(",")})`;
}
