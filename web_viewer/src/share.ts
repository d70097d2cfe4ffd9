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

export function formatHash(c: Credentials): string {
  return `#session=${encodeURIComponent(c.sessionId)}&token=${encodeURIComponent(c.token)}`;
}

/** origin + pathname + fragment: drops the query (e.g. ?sample=) so the link opens the session. */
export function shareLink(origin: string, pathname: string, c: Credentials): string {
  return origin + pathname + formatHash(c);
}
