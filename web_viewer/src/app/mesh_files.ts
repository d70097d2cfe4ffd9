// Mesh files in and out of the page: an upload becomes a new session (with the server's parse
// progress), a download is the session's mesh at the revision on screen.
import { Code } from "@connectrpc/connect";
import { MeshFormat, type CreateSessionResponse } from "../gen/meshdeform/v1/deformation_pb";
import { errorCode } from "../errors";
import { progressText, readWithProgress } from "../progress";
import type { Credentials } from "../share";
import { client, FORMATS, LAMBDA } from "./config";

/** The format of a file name's extension, or null when the server reads no such files. */
export function formatOfName(name: string): { ext: string; format: MeshFormat | null } {
  const ext = name.split(".").pop()?.toLowerCase() ?? "";
  return { ext, format: FORMATS[ext] ?? null };
}

/** Uploads `file` as a new session (OBJ and STL welded), reporting the upload's and the parse's
 * progress through `status`. */
export async function createSessionFromFile(file: File, format: MeshFormat, status: (text: string) => void): Promise<CreateSessionResponse> {
  const bytes = new Uint8Array(await file.arrayBuffer());
  status(`Uploading ${file.name} (${(bytes.length / 1024).toFixed(0)} KiB)…`);
  return readWithProgress<CreateSessionResponse>(
    client.createSessionWithProgress({ source: { case: "meshBytes", value: bytes }, format, lambda: LAMBDA, weld: format === MeshFormat.STL || format === MeshFormat.OBJ }),
    (p) => status(progressText(`Uploading ${file.name}…`, p)),
  );
}

/** Saves the session's mesh at `revision` (the current one when the server no longer keeps it)
 * as a file through the browser's download. */
export async function downloadMesh(creds: Credentials, revision: number, format: MeshFormat, ext: string, mime: string): Promise<void> {
  const r = await client.getMesh({ sessionId: creds.sessionId, token: creds.token, format, revision: BigInt(Math.max(0, revision)) }).catch((e) => {
    if (errorCode(e) !== Code.NotFound) throw e;
    return client.getMesh({ sessionId: creds.sessionId, token: creds.token, format });
  });
  const url = URL.createObjectURL(new Blob([r.meshBytes as BlobPart], { type: mime }));
  const a = document.createElement("a");
  a.href = url;
  a.download = `meshdeform-${creds.sessionId.slice(0, 8)}-r${revision}.${ext}`;
  document.body.appendChild(a);
  a.click();
  a.remove();
  setTimeout(() => URL.revokeObjectURL(url), 10_000);
}
