// Training runs in words: what each stage, kind and status means (worker/progress.py STAGE_WEIGHTS names the stages).
const STAGE_WORDS = {
  queued: "waiting for a training worker",
  starting: "getting ready",
  var_finetune: "learning your words",
  policy_improve: "practising in the simulator",
  evaluate: "testing the new version against the one in use",
  promoting: "deciding which version to keep",
  done: "done",
  succeeded: "done",
  failed: "stopped by an error",
  cancelled: "cancelled",
};
const KIND_WORDS = {
  finetune: "learn your words, practise, test",
  var_finetune: "learn your words, test",
  policy_improve: "practise, test",
  evaluate: "test the version in use",
};
const STATUS_WORDS = { queued: "waiting", running: "running", succeeded: "finished", failed: "failed", cancelled: "cancelled" };

const plain = (code) => code.replaceAll("_", " ");
export const stageWords = (stage) => STAGE_WORDS[stage] || plain(stage);
export const kindWords = (kind) => KIND_WORDS[kind] || plain(kind);
export const statusWords = (status) => STATUS_WORDS[status] || plain(status);
