// The list of handle groups in the side panel: click selects, × deletes.
import { cssColor, groupColor, type GroupSet } from "../groups";
import { $ } from "./dom";

export function renderGroupList(groups: GroupSet | null, dirty: boolean, editable: boolean, on: { select(i: number): void; remove(i: number): void }): void {
  const ul = $("group-list");
  ul.replaceChildren();
  if (!groups || groups.size === 0) {
    const li = document.createElement("li");
    li.className = "empty";
    li.textContent = "No groups yet: paint with Brush or Lasso.";
    ul.append(li);
    return;
  }
  for (let i = 0; i < groups.size; i++) {
    const role = groups.role(i);
    const li = document.createElement("li");
    li.dataset.testid = `group-item-${i}`;
    li.classList.toggle("sel", i === groups.selected);
    const sw = document.createElement("i");
    sw.style.background = cssColor(groupColor(role, groups.ordinal(i)));
    const label = document.createElement("span");
    label.textContent = `${role === "fixed" ? "Fixed" : "Handle"} ${groups.ordinal(i) + 1}`;
    const count = document.createElement("span");
    count.className = "count";
    count.textContent = `${groups.count(i).toLocaleString("en")} v`;
    const del = document.createElement("button");
    del.textContent = "×";
    del.title = "Delete this group";
    del.setAttribute("aria-label", `Delete ${label.textContent}`);
    del.dataset.testid = `group-delete-${i}`;
    del.disabled = !editable;
    del.addEventListener("click", (e) => {
      e.stopPropagation();
      on.remove(i);
    });
    li.append(sw, label, count, del);
    li.addEventListener("click", () => on.select(i));
    ul.append(li);
  }
  if (dirty) {
    const li = document.createElement("li");
    li.className = "empty";
    // What to do about it is the state notice's (it knows the tool and what is missing).
    li.textContent = "Not applied yet.";
    ul.append(li);
  }
}
