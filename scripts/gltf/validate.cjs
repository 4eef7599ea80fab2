// Validates a glTF file with the Khronos glTF validator (npm package gltf-validator, installed by
// scripts/test.sh into target/npm) and prints its report as JSON. Usage: node validate.cjs <file.glb>
const fs = require("fs");
const path = require("path");
const validator = require("gltf-validator");

const file = process.argv[2];
const bytes = new Uint8Array(fs.readFileSync(file));
validator
  .validateBytes(bytes, {
    uri: path.basename(file),
    maxIssues: 100,
    externalResourceFunction: (uri) => Promise.reject(new Error(`no external resources: ${uri}`)),
  })
  .then((report) => {
    process.stdout.write(JSON.stringify(report));
  })
  .catch((error) => {
    process.stderr.write(`validation failed: ${error}\n`);
    process.exit(2);
  });
