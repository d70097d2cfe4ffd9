// Element lookup and the status / error / progress banner.
import { Code, ConnectError } from "@connectrpc/connect";

export function $(id: string): HTMLElement {
  const el = document.getElementById(id);
  if (!el) throw new Error(`missing #${id}`);
  return el;
}
export const $in = (id: string) => $(id) as HTMLInputElement;
export const $sel = (id: string) => $(id) as HTMLSelectElement;
export const $btn = (id: string) => $(id) as HTMLButtonElement;

/** "INVALID_ARGUMENT: message" from any error (gRPC code names as in the proto docs). */
export function describeError(e: unknown): { code: string; text: string } {
  if (e instanceof ConnectError || (e && typeof e === "object" && "code" in e && "rawMessage" in e)) {
    const ce = ConnectError.from(e);
    const code = grpcCodeName(ce.code);
    return { code, text: `${code}: ${ce.rawMessage}` };
  }
  const msg = e instanceof Error ? e.message : String(e);
  return { code: "", text: msg };
}

export function grpcCodeName(c: Code): string {
  // Code.InvalidArgument -> "INVALID_ARGUMENT"
  return (Code[c] ?? "UNKNOWN").replace(/([a-z])([A-Z])/g, "$1_$2").toUpperCase();
}

export class Banner {
  private progressDepth = 0;
  constructor(private onError: (text: string) => void) {
    $("error-close").addEventListener("click", () => this.clearError());
  }
  status(text: string): void {
    $("status").textContent = text;
  }
  error(prefix: string, e: unknown): string {
    const text = prefix ? `${prefix}: ${describeError(e).text}` : describeError(e).text;
    $("error-text").textContent = text;
    $("error").hidden = false;
    this.onError(text);
    console.warn(text, e);
    return text;
  }
  message(text: string): void {
    $("error-text").textContent = text;
    $("error").hidden = false;
    this.onError(text);
  }
  clearError(): void {
    $("error").hidden = true;
    $("error-text").textContent = "";
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
