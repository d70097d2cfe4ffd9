// The centred notice for a link that cannot be opened, with its way out (a new session), and the
// first-visit hint on the demo link.
import { $ } from "./dom";

const HINT_KEY = "meshdeform.firstHintSeen";

export function showLinkProblem(detail: string, onNewSession: () => void): void {
  $("notice-text").textContent = detail;
  $("notice").hidden = false;
  $("new-session").onclick = onNewSession;
}

export function hideLinkProblem(): void {
  $("notice").hidden = true;
}

function hintSeen(): boolean {
  try {
    return localStorage.getItem(HINT_KEY) === "1";
  } catch {
    return false;
  }
}

/** Shows "drag the orange handle" unless this browser has dismissed it before. */
export function showFirstHint(): void {
  if (hintSeen()) return;
  $("first-hint").hidden = false;
  $("first-hint-close").onclick = () => dismissFirstHint();
}

/** Hides the hint for good (after the first drag, or its button). */
export function dismissFirstHint(): void {
  if ($("first-hint").hidden) return;
  $("first-hint").hidden = true;
  try {
    localStorage.setItem(HINT_KEY, "1");
  } catch {
    /* private mode: it shows again next visit */
  }
}
