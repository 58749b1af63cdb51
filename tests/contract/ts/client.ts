// A TypeScript program written against the types generated from openapi/openapi.json (openapi-typescript,
// tools/spec/generate-types.mjs) and openapi-fetch: it must compile under `tsc --strict`, uploads
// included, and (run by node) analyse a clip end to end against a live server.
//
//   node client.js BASE_URL CLIP_PATH   -> one JSON line: what it did and found
import createClient from "openapi-fetch";
import { readFileSync } from "node:fs";
import type { components, paths } from "./schema";

type Job = components["schemas"]["Job"];
type QualityCode = components["schemas"]["QualityFlag"]["code"];
type Stage = NonNullable<Job["stage"]>;
type ArtifactName = paths["/v1/jobs/{job_id}/artifacts/{name}"]["get"]["parameters"]["path"]["name"];
type PollHeaders = NonNullable<paths["/v1/jobs/{job_id}"]["get"]["parameters"]["header"]>;

// The enumerations are the API's: a misspelt value does not compile.
// @ts-expect-error "posibly_aliased" is not a quality code
export const misspelt: QualityCode = "posibly_aliased";
// @ts-expect-error "render" is not a stage (it is "rendering")
export const oldStage: Stage = "render";
// @ts-expect-error an artifact is named by the enumeration
export const unknownArtifact: ArtifactName = "mask.jpg";
// @ts-expect-error an optional header is left out, never sent as null
export const nullTag: PollHeaders = { "If-None-Match": null };
// @ts-expect-error a step release needs its force
export const forceless: components["schemas"]["JobCreate"] = { clip_id: "c", excitation: { type: "step_release" } };

function fail(what: string, detail: unknown): never {
  throw new Error(`${what}: ${JSON.stringify(detail)}`);
}

export async function main(baseUrl: string, clipPath: string): Promise<Record<string, unknown>> {
  const client = createClient<paths>({ baseUrl });

  // The upload: a Blob in the body, sent as multipart/form-data.
  const file: Blob = new Blob([readFileSync(clipPath)]);
  const uploaded = await client.POST("/v1/clips", {
    body: { file },
    bodySerializer(body) {
      const form = new FormData();
      form.append("file", body.file, "clip.npz");
      return form;
    },
    params: { header: { "Idempotency-Key": `ts-${Date.now()}` } },
  });
  if (!uploaded.data) fail("upload", uploaded.error);
  const clip = uploaded.data;

  const created = await client.POST("/v1/jobs", {
    body: { clip_id: clip.id, excitation: { type: "step_release", force_n: 5.0 } },
  });
  if (!created.data) fail("create_job", created.error);
  // The 202's ETag is the job's: the first poll already long-polls for a change.
  let etag: string | undefined = created.response.headers.get("ETag") ?? undefined;
  let job: Job = created.data;
  let notModified = 0;
  const stages = new Set<Stage>();
  while (job.status === "queued" || job.status === "running") {
    const headers: PollHeaders = etag === undefined ? {} : { "If-None-Match": etag };
    const polled = await client.GET("/v1/jobs/{job_id}", {
      params: { path: { job_id: job.id }, query: { wait: 20 }, header: headers },
    });
    if (polled.response.status === 304) {
      notModified += 1;
      continue;
    }
    if (!polled.data) fail("get_job", polled.error);
    job = polled.data;
    if (job.stage) stages.add(job.stage);
    etag = polled.response.headers.get("ETag") ?? undefined;
  }
  if (job.status !== "succeeded") fail("job", job.error);

  const result = await client.GET("/v1/jobs/{job_id}/result", { params: { path: { job_id: job.id } } });
  if (!result.data) fail("get_job_result", result.error);
  const codes: QualityCode[] = result.data.quality.map((q) => q.code);
  const listed = await client.GET("/v1/jobs", { params: { query: { clip_id: clip.id } } });
  if (!listed.data) fail("list_jobs", listed.error);
  const summary = listed.data.items[0]?.summary;
  const mask = await client.GET("/v1/jobs/{job_id}/artifacts/{name}", {
    params: { path: { job_id: job.id, name: "mask.png" } },
    parseAs: "arrayBuffer",
  });
  if (!mask.data) fail("get_job_artifact", mask.error);
  const png = new Uint8Array(mask.data).slice(0, 4);
  return {
    clip: clip.id,
    format: clip.format,
    job: job.id,
    status: job.status,
    not_modified: notModified,
    stages: [...stages],
    eigenfrequency_hz: result.data.eigenfrequency_hz,
    flow: result.data.parameters.flow,
    quality: codes,
    summary_hz: summary?.eigenfrequency_hz ?? null,
    result_url: listed.data.items[0]?.result_url ?? null,
    mask_magic: Array.from(png),
  };
}

const [baseUrl, clipPath] = process.argv.slice(2);
if (baseUrl !== undefined && clipPath !== undefined) {
  main(baseUrl, clipPath).then(
    (report) => console.log(JSON.stringify(report)),
    (error: unknown) => {
      console.error(error);
      process.exit(1);
    },
  );
}
