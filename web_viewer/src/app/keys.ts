// The page's keyboard: an open G / R / S command takes every key first; then undo and redo
// (Ctrl+Z, Ctrl+Shift+Z, Ctrl+Y), the axis views (1 / 3 / 7, Ctrl: the opposite side), F or Home
// to frame the mesh, Del to remove the selected group, and G / R / S to open a command. Keys typed
// into a text field or a select are theirs. Owns nothing: the page is the host.
import { viewForKey, type ViewName } from "../views";

/** What the keys act on. */
export interface KeysHost {
  modal: {
    readonly active: boolean;
    feed(key: string): void;
    /** Opens the command a key starts. @return whether the key was one. */
    start(key: string): boolean;
  };
  undoRedo(redo: boolean): void;
  setView(view: ViewName): void;
  frame(): void;
  canEdit(): boolean;
  /** The selected group (-1 for none) and its removal. */
  selectedGroup(): number;
  deleteGroup(i: number): void;
}

/** The element a key went to takes it itself: a text field (not a slider or a checkbox), a
 * select or a text area. */
export function isTyping(el: { tagName: string; type?: string } | null): boolean {
  return (el?.tagName === "INPUT" && el.type !== "range" && el.type !== "checkbox") || el?.tagName === "SELECT" || el?.tagName === "TEXTAREA";
}

export function onKey(e: KeyboardEvent, host: KeysHost): void {
  if (isTyping(e.target as HTMLElement | null)) return;
  if (host.modal.active && !e.ctrlKey && !e.metaKey && !e.altKey) {
    e.preventDefault();
    host.modal.feed(e.key);
    return;
  }
  if ((e.ctrlKey || e.metaKey) && e.key.toLowerCase() === "z") {
    e.preventDefault();
    host.undoRedo(e.shiftKey);
    return;
  }
  if ((e.ctrlKey || e.metaKey) && e.key.toLowerCase() === "y") {
    e.preventDefault();
    host.undoRedo(true);
    return;
  }
  const view = !e.altKey && !e.metaKey ? viewForKey(e.code, e.key, e.ctrlKey) : null;
  if (view) {
    e.preventDefault();
    host.setView(view);
    return;
  }
  if (!e.ctrlKey && !e.metaKey && !e.altKey && (e.key === "Home" || e.key === "f" || e.key === "F")) {
    e.preventDefault();
    host.frame();
    return;
  }
  if (!e.ctrlKey && !e.metaKey && !e.altKey && host.canEdit()) {
    if (e.key === "Delete") {
      const i = host.selectedGroup();
      if (i >= 0) {
        e.preventDefault();
        host.deleteGroup(i);
      }
    } else if (host.modal.start(e.key)) {
      e.preventDefault();
    }
  }
}
