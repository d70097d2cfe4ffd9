// Errors in plain words: one mapping from a gRPC status code to a sentence a user can act on.
// The code and the server's own message go in small print underneath.
import { Code, ConnectError } from "@connectrpc/connect";

/** What the user was doing; a few codes read better with it. */
export type Action = "open" | "create" | "upload" | "handles" | "move" | "reset" | "download" | "watch" | "other";

/** The plain sentence for `code` (null: not a gRPC error, e.g. a broken response). */
export function plainSentence(code: Code | null, action: Action = "other"): string {
  switch (code) {
    case Code.InvalidArgument:
      if (action === "upload") return "The file could not be read as a mesh.";
      if (action === "open") return "This link is malformed.";
      return "The server refused the request as invalid.";
    case Code.NotFound:
      return "This session is gone: it was closed, expired or the server restarted.";
    case Code.PermissionDenied:
      return action === "open" ? "This link's token does not open this session." : "This link only allows watching, not editing.";
    case Code.FailedPrecondition:
      return "Not possible with these handles: every separate part of the mesh needs enough fixed or handle vertices.";
    case Code.ResourceExhausted:
      return "The server is at a limit (too many sessions, too large a mesh, or busy). Try again shortly or use a smaller mesh.";
    case Code.DeadlineExceeded:
      return "The server took too long, so nothing changed. Try fewer iterations or a smaller mesh.";
    case Code.Canceled:
      return "The request was cancelled; nothing changed.";
    case Code.Unavailable:
      return "The server cannot be reached. Check that it is running and the connection is up.";
    case Code.Internal:
      return "The solver failed on this input. Try another method or other handles.";
    case Code.Unimplemented:
      return "The server does not support this request (it may be an older version).";
    case Code.Unauthenticated:
      return "The server did not accept the credentials.";
    case null:
      return "Something unexpected went wrong.";
    default:
      return "The server reported an error.";
  }
}

/** "INVALID_ARGUMENT" from Code.InvalidArgument (the names the proto documents). */
export function grpcCodeName(c: Code): string {
  return (Code[c] ?? "UNKNOWN").replace(/([a-z])([A-Z])/g, "$1_$2").toUpperCase();
}

export interface Described {
  code: Code | null;
  /** Plain words, for everyone. */
  sentence: string;
  /** Small print: "CODE: server message", or the error's own message. */
  detail: string;
}

export function describeError(e: unknown, action: Action = "other"): Described {
  if (e instanceof ConnectError || (e && typeof e === "object" && "code" in e && "rawMessage" in e)) {
    const ce = ConnectError.from(e);
    return { code: ce.code, sentence: plainSentence(ce.code, action), detail: `${grpcCodeName(ce.code)}: ${ce.rawMessage}` };
  }
  const msg = e instanceof Error ? e.message : String(e);
  return { code: null, sentence: plainSentence(null, action), detail: msg };
}

/** The code of a gRPC error, else null. */
export function errorCode(e: unknown): Code | null {
  return e instanceof ConnectError || (e && typeof e === "object" && "code" in e && "rawMessage" in e) ? ConnectError.from(e).code : null;
}
