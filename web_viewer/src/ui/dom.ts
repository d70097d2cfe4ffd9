// Element lookup and the status / error / progress banner.
import { describeError, type Action } from "../errors";

export function $(id: string): HTMLElement {
  const el = document.getElementById(id);
  if (!el) throw new Error(`missing #${id}`);
  return el;
}
export const $in = (id: string) => $(id) as HTMLInputElement;
export const $sel = (id: string) => $(id) as HTMLSelectElement;
export const $btn = (id: string) => $(id) as HTMLButtonElement;

export class Banner {
  private progressDepth = 0;
  constructor(private onError: (text: string) => void) {
    $("error-close").addEventListener("click", () => this.clearError());
  }
  status(text: string): void {
    $("status").textContent = text;
  }
  /** "<prefix>: <plain sentence>", with the gRPC code and server message in small print. */
  error(prefix: string, e: unknown, action: Action = "other"): string {
    const d = describeError(e, action);
    const text = prefix ? `${prefix}: ${d.sentence}` : d.sentence;
    $("error-text").textContent = text;
    $("error-detail").textContent = d.detail;
    $("error").hidden = false;
    this.onError(`${text} [${d.detail}]`);
    console.warn(text, d.detail);
    return text;
  }
  message(text: string): void {
    $("error-text").textContent = text;
    $("error-detail").textContent = "";
    $("error").hidden = false;
    this.onError(text);
  }
  clearError(): void {
    $("error").hidden = true;
    $("error-text").textContent = "";
    $("error-detail").textContent = "";
    this.onError("");
  }
  /** Shows the spinner with `text` while `work` runs (nested calls keep it up). */
  async progress<T>(text: string, work: () => Promise<T>): Promise<T> {
    this.progressDepth++;
    $("progress-text").textContent = text;
    $("progress").hidden = false;
    try {
      return await work();
    } finally {
      if (--this.progressDepth === 0) $("progress").hidden = true;
    }
  }
}
