// Share links carry the credentials in the URL fragment, which browsers never send to the
// server, so tokens do not end up in access logs.

export interface Credentials {
  sessionId: string;
  token: string;
}

export function parseHash(hash: string): Credentials | null {
  const h = hash.startsWith("#") ? hash.slice(1) : hash;
  const q = new URLSearchParams(h);
  const sessionId = q.get("session") ?? "";
  const token = q.get("token") ?? "";
  return sessionId && token ? { sessionId, token } : null;
}

/** What the fragment asks for: nothing (a demo session), a session, or a link missing a part. */
export type LinkRequest =
  | { kind: "none" }
  | { kind: "session"; creds: Credentials }
  | { kind: "incomplete"; missing: "token" | "session" };

/** Like parseHash, but tells a broken link apart from no link, so that a link with a session and
 * no token is reported instead of being silently replaced by a new session. */
export function parseLink(hash: string): LinkRequest {
  const h = hash.startsWith("#") ? hash.slice(1) : hash;
  const q = new URLSearchParams(h);
  const sessionId = (q.get("session") ?? "").trim();
  const token = (q.get("token") ?? "").trim();
  if (sessionId && token) return { kind: "session", creds: { sessionId, token } };
  if (sessionId) return { kind: "incomplete", missing: "token" };
  if (token || q.has("session") || q.has("token")) return { kind: "incomplete", missing: "session" };
  return { kind: "none" };
}

export function formatHash(c: Credentials): string {
  return `#session=${encodeURIComponent(c.sessionId)}&token=${encodeURIComponent(c.token)}`;
}

/** origin + pathname + fragment: drops the query (e.g. ?sample=) so the link opens the session. */
export function shareLink(origin: string, pathname: string, c: Credentials): string {
  return origin + pathname + formatHash(c);
}
