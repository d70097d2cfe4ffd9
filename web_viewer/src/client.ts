// gRPC-Web transport and typed client for meshdeform.v1.DeformationService.
import { createClient, createContextKey, type Client, type Interceptor } from "@connectrpc/connect";
import { createGrpcWebTransport } from "@connectrpc/connect-web";
import { DeformationService } from "./gen/meshdeform/v1/deformation_pb";

export type DeformClient = Client<typeof DeformationService>;

/** Server-streaming requests hide their message behind an async iterable, so Watch passes the
 * session id through a context value instead; unary calls read the request field. */
export const kSessionId = createContextKey<string>("", { description: "x-session-id" });

/** Adds `x-session-id` to every per-session call so a load balancer can route on it. */
export const sessionHeaderInterceptor: Interceptor = (next) => async (req) => {
  let sid = req.contextValues.get(kSessionId);
  if (!sid && !req.stream) {
    const m = req.message as { sessionId?: unknown };
    if (typeof m.sessionId === "string") sid = m.sessionId;
  }
  if (sid) req.header.set("x-session-id", sid);
  return next(req);
};

export function makeClient(baseUrl: string): DeformClient {
  const transport = createGrpcWebTransport({
    baseUrl,
    useBinaryFormat: true,
    interceptors: [sessionHeaderInterceptor],
  });
  return createClient(DeformationService, transport);
}
