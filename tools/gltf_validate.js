#!/usr/bin/env node
// Validate a glTF 2.0 file with the Khronos glTF-Validator (npm package "gltf-validator").
// Usage: node tools/gltf_validate.js FILE.glb|FILE.gltf
// Prints the validator's JSON report on stdout; exit code 0 if it has no errors, 1 if it has,
// 2 if the file could not be validated. The package is installed by `make setup` into .node/.
"use strict";
const fs = require("fs");
const path = require("path");
let validator;
try {
  validator = require(path.join(__dirname, "..", ".node", "node_modules", "gltf-validator"));
} catch (e) {
  validator = require("gltf-validator");
}
const file = process.argv[2];
if (!file) {
  console.error("usage: node tools/gltf_validate.js FILE.glb");
  process.exit(2);
}
const dir = path.dirname(file);
validator
  .validateBytes(new Uint8Array(fs.readFileSync(file)), {
    uri: path.basename(file),
    externalResourceFunction: (uri) =>
      new Promise((resolve, reject) => {
        fs.readFile(path.join(dir, decodeURIComponent(uri)), (err, data) =>
          err ? reject(err.toString()) : resolve(new Uint8Array(data)));
      }),
  })
  .then((report) => {
    console.log(JSON.stringify(report, null, 1));
    process.exit(report.issues.numErrors > 0 ? 1 : 0);
  })
  .catch((err) => {
    console.error(String(err));
    process.exit(2);
  });
