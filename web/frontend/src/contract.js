// What the server sends, read from its JSON Schema rather than guessed: GET /api/schemas/task is the
// schema of a task's detail (GET /api/tasks/{id}), and its `summary` is the store's TaskSummary
// contract (lidarfuzz.store.contracts; GET /api/schemas/summary). The statuses a task or subtask
// takes are the schema's enum and the ones it ends in its `x-final-statuses`, so a status the
// server adds needs no change here. tests/web/test_contract.py checks that every task, subtask and
// AP field these pages read is declared by the schema.
import { api } from "./api.js";

let loading = null;

// The task-detail schema, fetched once per page load.
export function taskSchema() {
  loading ??= api("/api/schemas/task").catch((exc) => {
    loading = null; // try again next time
    throw exc;
  });
  return loading;
}

function definition(schema, ref) {
  return schema.$defs?.[ref.split("/").pop()] ?? {};
}

// A property's schema with $ref and nullable (anyOf [X, null]) unwrapped.
function property(schema, node, name) {
  let prop = node.properties?.[name] ?? {};
  const options = prop.anyOf?.filter((option) => option.type !== "null");
  if (options?.length === 1) prop = options[0];
  return prop.$ref ? definition(schema, prop.$ref) : prop;
}

// {statuses, finished, isFinished(status)}: every status of a task (the schema's enum) and the
// ones it ends in.
export function statusesOf(schema) {
  const statuses = property(schema, schema, "status").enum ?? [];
  const finished = new Set(schema["x-final-statuses"] ?? []);
  if (!statuses.length || !finished.size) throw new Error("the server's task schema lists no statuses");
  return { statuses, finished, isFinished: (status) => finished.has(String(status)) };
}
