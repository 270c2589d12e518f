// Compare ROS 2 message definitions we ship for foxglove_msgs with Foxglove's own.
//
//   node schemas.mjs DIR
//
// For each DIR/NAME.msg: Foxglove's generator (@foxglove/schemas, the source of the
// foxglove_msgs package) writes the ROS 2 definition of NAME; both texts are parsed with
// @foxglove/rosmsg and must define the same fields and constants in the same order (comments
// and blank lines aside). Prints {"NAME": null | "what differs"} and exits 1 on a difference.

import { readdirSync, readFileSync } from "node:fs";
import { join } from "node:path";
import { parse } from "@foxglove/rosmsg";
import { foxgloveMessageSchemas, generateRosMsg, generateRosMsgDefinition } from "@foxglove/schemas/internal.js";

function fields(text) {
  const [top] = parse(text, { ros2: true, skipTypeFixup: true });
  return top.definitions.map(({ name, type, isArray, arrayLength, isConstant, value }) => ({
    name, type, isArray: isArray ?? false, arrayLength: arrayLength ?? null, isConstant: isConstant ?? false,
    value: value === undefined ? null : String(value),
  }));
}

const dir = process.argv[2];
const report = {};
let failed = false;
for (const file of readdirSync(dir).filter((f) => f.endsWith(".msg")).sort()) {
  const name = file.slice(0, -4);
  const schema = foxgloveMessageSchemas[name];
  if (schema === undefined) {
    report[name] = "not a Foxglove schema";
    failed = true;
    continue;
  }
  const theirs = JSON.stringify(fields(generateRosMsg(generateRosMsgDefinition(schema, { rosVersion: 2 }),
    { rosVersion: 2 })));
  const ours = JSON.stringify(fields(readFileSync(join(dir, file), "utf8")));
  report[name] = ours === theirs ? null : `ours ${ours}\ntheirs ${theirs}`;
  failed ||= ours !== theirs;
}
process.stdout.write(JSON.stringify(report, null, 1) + "\n");
process.exitCode = failed ? 1 : 0;
