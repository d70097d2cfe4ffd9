import { describe, expect, it } from "vitest";
import { formatHash, parseHash, shareLink } from "../src/share";

describe("share links", () => {
  it("formats and parses the fragment", () => {
    const c = { sessionId: "s-1/2", token: "t+k=" };
    const h = formatHash(c);
    expect(h.startsWith("#session=")).toBe(true);
    expect(parseHash(h)).toEqual(c);
    expect(parseHash(h.slice(1))).toEqual(c);
  });
  it("returns null without both fields", () => {
    expect(parseHash("")).toBeNull();
    expect(parseHash("#session=abc")).toBeNull();
    expect(parseHash("#token=abc")).toBeNull();
  });
  it("builds origin + path + fragment (no query)", () => {
    expect(shareLink("http://127.0.0.1:8080", "/viewer/", { sessionId: "a", token: "b" })).toBe(
      "http://127.0.0.1:8080/viewer/#session=a&token=b",
    );
  });
});
