import { describe, expect, it } from "vitest";
import { phaseLabel, progressText, readWithProgress, type ProgressEvent } from "../src/progress";

async function* events<R>(list: ProgressEvent<R>[]): AsyncIterable<ProgressEvent<R>> {
  for (const e of list) yield e;
}

const progress = (phase: string, fraction: number, elapsedSeconds = 0): ProgressEvent<string> => ({
  event: { case: "progress", value: { phase, fraction, elapsedSeconds } },
});

describe("progress", () => {
  it("names the server's phases and passes unknown ones through", () => {
    expect(phaseLabel("decimate")).toBe("building the coarse level");
    expect(phaseLabel("parse")).toBe("reading the mesh");
    expect(phaseLabel("some_new_phase")).toBe("some new phase");
  });

  it("shows a percentage only inside a phase", () => {
    expect(progressText("Factorizing…", { phase: "decimate", fraction: 0.426, elapsedSeconds: 1.27 })).toBe(
      "Factorizing… building the coarse level 42% · 1.3 s",
    );
    expect(progressText("Factorizing…", { phase: "step_two", fraction: 0, elapsedSeconds: 2 })).toBe(
      "Factorizing… factorizing the solver · 2.0 s",
    );
    expect(progressText("Factorizing…", { phase: "step_two", fraction: 1, elapsedSeconds: 2 })).not.toContain("%");
  });

  it("reports progress in order and returns the response", async () => {
    const seen: string[] = [];
    const r = await readWithProgress(
      events<string>([progress("queued", 0), progress("queued", 1), progress("parse", 0.5), { event: { case: "response", value: "done" } }]),
      (p) => seen.push(`${p.phase}:${p.fraction}`),
    );
    expect(r).toBe("done");
    expect(seen).toEqual(["queued:0", "queued:1", "parse:0.5"]);
  });

  it("fails when the stream ends without a response", async () => {
    await expect(readWithProgress(events<string>([progress("queued", 0)]), () => undefined)).rejects.toThrow(/without a response/);
  });

  it("passes the stream's error on", async () => {
    async function* failing(): AsyncIterable<ProgressEvent<string>> {
      yield progress("parse", 0);
      throw new Error("INVALID_ARGUMENT: face 2 references vertex 9");
    }
    const seen: string[] = [];
    await expect(readWithProgress(failing(), (p) => seen.push(p.phase))).rejects.toThrow(/face 2/);
    expect(seen).toEqual(["parse"]);
  });
});
