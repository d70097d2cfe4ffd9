// The state notice (issue 44: every state has a way out): what is missing for dragging (no
// groups, no handle, no fixed region, groups painted but not applied), in words, with the buttons
// that fix it. app/groups_controller.ts recomputes it on every change, so it never outlives
// its cause.
import { $ } from "./dom";

export interface NoticeAction {
  id: string;
  label: string;
  run: () => void;
}

export function showStateNotice(text: string, actions: NoticeAction[]): void {
  $("state-notice-text").textContent = text;
  const box = $("state-notice-actions");
  box.replaceChildren(...actions.map((a) => {
    const b = document.createElement("button");
    b.textContent = a.label;
    b.dataset.testid = a.id;
    b.id = a.id;
    b.addEventListener("click", () => a.run());
    return b;
  }));
  $("state-notice").hidden = false;
}

export function clearStateNotice(): void {
  $("state-notice").hidden = true;
  $("state-notice-text").textContent = "";
  $("state-notice-actions").replaceChildren();
}
