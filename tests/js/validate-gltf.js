// Runs Khronos' glTF-Validator on one .gltf or .glb file (external buffers resolved next to it)
// and prints the report as JSON on stdout. Exit code: 0 when the validator ran (whatever it
// found; the caller judges the counts), 1 when it could not run or read the file.
'use strict';
const fs = require('fs');
const path = require('path');
const validator = require('gltf-validator');

const file = process.argv[2];
if (!file) {
  console.error('usage: node validate-gltf.js FILE.gltf|FILE.glb');
  process.exit(1);
}
const fullpath = path.resolve(file);
const asset = fs.readFileSync(fullpath);
validator
  .validateBytes(new Uint8Array(asset), {
    uri: path.basename(fullpath),
    maxIssues: 0,
    writeTimestamp: false,
    externalResourceFunction: (uri) =>
      new Promise((resolve, reject) => {
        const resolved = path.resolve(path.dirname(fullpath), decodeURIComponent(uri));
        fs.readFile(resolved, (err, data) => (err ? reject(err.toString()) : resolve(new Uint8Array(data))));
      }),
  })
  .then(
    (report) => {
      process.stdout.write(JSON.stringify(report, null, 2) + '\n');
    },
    (err) => {
      console.error('glTF-Validator could not run: ' + err);
      process.exit(1);
    },
  );
