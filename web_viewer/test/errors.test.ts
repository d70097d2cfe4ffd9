import { describe, expect, it } from "vitest";
import { Code, ConnectError } from "@connectrpc/connect";
import { describeError, errorCode, grpcCodeName, plainSentence } from "../src/errors";
import { MAX_ITERATIONS, parseIterations } from "../src/iterations";
import { parseLink } from "../src/share";

describe("error wording", () => {
  it("maps codes to plain sentences without jargon", () => {
    for (const c of [Code.InvalidArgument, Code.NotFound, Code.PermissionDenied, Code.FailedPrecondition, Code.ResourceExhausted, Code.DeadlineExceeded, Code.Unavailable, Code.Internal, null]) {
      const s = plainSentence(c);
      expect(s).toMatch(/^[A-Z].*\.$/);
      expect(s).not.toMatch(/_|grpc|RPC/i);
    }
    expect(plainSentence(Code.NotFound)).toMatch(/session is gone/);
    expect(plainSentence(Code.InvalidArgument, "upload")).toMatch(/file could not be read/);
  });

  it("puts the code and server message in the detail", () => {
    const d = describeError(new ConnectError("OBJ line 3: bad face", Code.InvalidArgument), "upload");
    expect(d.code).toBe(Code.InvalidArgument);
    expect(d.sentence).toBe("The file could not be read as a mesh.");
    expect(d.detail).toBe("INVALID_ARGUMENT: OBJ line 3: bad face");
    const o = describeError(new Error("GLB has 3 vertices"));
    expect(o.code).toBeNull();
    expect(o.detail).toBe("GLB has 3 vertices");
    expect(errorCode(new ConnectError("x", Code.NotFound))).toBe(Code.NotFound);
    expect(errorCode(new Error("x"))).toBeNull();
    expect(grpcCodeName(Code.ResourceExhausted)).toBe("RESOURCE_EXHAUSTED");
  });
});

describe("iterations field", () => {
  it("accepts whole numbers 1..1000", () => {
    expect(parseIterations("2")).toEqual({ ok: true, value: 2 });
    expect(parseIterations(" 1000 ")).toEqual({ ok: true, value: MAX_ITERATIONS });
    expect(parseIterations("1")).toEqual({ ok: true, value: 1 });
  });
  it("refuses 0, negatives, fractions, huge values and text", () => {
    for (const t of ["0", "-3", "2.5", "1001", "1e9", "99999999999", "", "abc"]) {
      const r = parseIterations(t);
      expect(r.ok, t).toBe(false);
      if (!r.ok) expect(r.reason).toMatch(/Iterations/);
    }
    const r = parseIterations("5000");
    expect(!r.ok && r.reason).toMatch(/at most 1000/);
  });
});

describe("links", () => {
  it("tells a broken link from no link", () => {
    expect(parseLink("")).toEqual({ kind: "none" });
    expect(parseLink("#")).toEqual({ kind: "none" });
    expect(parseLink("#session=abc")).toEqual({ kind: "incomplete", missing: "token" });
    expect(parseLink("#session=abc&token=")).toEqual({ kind: "incomplete", missing: "token" });
    expect(parseLink("#token=t")).toEqual({ kind: "incomplete", missing: "session" });
    expect(parseLink("#session=&token=")).toEqual({ kind: "incomplete", missing: "session" });
    expect(parseLink("#session=a%2Fb&token=t%2B")).toEqual({ kind: "session", creds: { sessionId: "a/b", token: "t+" } });
  });
});
