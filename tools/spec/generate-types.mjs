// The TypeScript types of an OpenAPI document, by openapi-typescript's Node API, with binary strings
// (`format: binary`: a clip upload's file, an image artifact) typed `Blob` as openapi-typescript's own
// documentation does it: so an upload passes a Blob (or a File) and type-checks under `tsc --strict`.
//
//   node generate-types.mjs ../../openapi/openapi.json schema.d.ts
import fs from "node:fs";
import path from "node:path";
import { pathToFileURL } from "node:url";
import openapiTS, { astToString } from "openapi-typescript";
import ts from "typescript";

const [input, output] = process.argv.slice(2);
if (!input || !output) {
  console.error("usage: node generate-types.mjs OPENAPI_JSON OUTPUT_D_TS");
  process.exit(2);
}
const BLOB = ts.factory.createTypeReferenceNode(ts.factory.createIdentifier("Blob"));
const NULL = ts.factory.createLiteralTypeNode(ts.factory.createNull());

const ast = await openapiTS(pathToFileURL(path.resolve(input)), {
  transform(schemaObject) {
    if (schemaObject.format === "binary") {
      return schemaObject.nullable ? ts.factory.createUnionTypeNode([BLOB, NULL]) : BLOB;
    }
    return undefined;
  },
});
fs.writeFileSync(output, astToString(ast));
