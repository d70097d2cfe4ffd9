// The session's Watch stream, read in a worker (src/mesh_worker.ts): the page opens it and gets
// the worker's messages as events; frames come at most one per animation frame, and the page
// hands each frame's buffers back (ack) once it is drawn.
import { ConnectError } from "@connectrpc/connect";
import type { FromWorker, ToWorker } from "../frames";

export type OpenWatch = Extract<ToWorker, { type: "open" }>;
export type Frame = Extract<FromWorker, { type: "frame" }>;

/** What the stream tells the page. */
export interface WatchEvents {
  frame(f: Frame): void;
  status(text: string): void;
  /** An update that did not decode (the stream goes on). */
  bad(message: string): void;
  /** The stream ended OK: the session was closed. */
  ended(): void;
  /** The stream failed (NOT_FOUND: the session is gone). */
  failed(e: ConnectError): void;
  /** The worker itself failed. */
  workerFailed(message: string): void;
}

/** Starts the worker and opens the stream (`open`'s arrays are transferred to the worker).
 * @return the worker: terminate() ends the stream; post acks and heat-map changes to it. */
export function openWatch(open: OpenWatch, events: WatchEvents): Worker {
  const w = new Worker(new URL("../mesh_worker.ts", import.meta.url), { type: "module" });
  w.onmessage = (ev: MessageEvent<FromWorker>) => {
    const m = ev.data;
    if (m.type === "frame") events.frame(m);
    else if (m.type === "status") events.status(m.text);
    else if (m.type === "bad") events.bad(m.message);
    else if (m.type === "end") events.ended();
    else if (m.type === "error") events.failed(new ConnectError(m.rawMessage, m.code));
  };
  w.onerror = (ev) => events.workerFailed(ev.message);
  w.postMessage(open, [open.indices.buffer, open.rest.buffer]);
  return w;
}
