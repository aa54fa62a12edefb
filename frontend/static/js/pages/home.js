// The first-run checklist: each step ticks itself off from the household's real state (robots, recordings per
// command, camera views, labels, runs), and links to the page where it is done.
import { api } from "../api.js";
import { groupCommands, targetCount, targetsSentence } from "../commands.js";
import { element, pageFailed, pageReady, robotPicker, say, startPage } from "../shell.js";

const $ = (id) => document.getElementById(id);
const TIMES_EACH = 2; // recordings of each command before labelling is worth it
let me;
let picker;

/** What the steps are judged on, for the chosen robot (or the household, where no robot is chosen). */
async function householdState(robot) {
  const query = robot ? `?robot_id=${robot.id}` : "";
  const [clips, views, stats, succeeded, unfinished] = await Promise.all([
    api("/clips?limit=1000"),
    robot ? api(`/snapshots?robot_id=${robot.id}&limit=1`) : Promise.resolve([]),
    api(`/triplets/stats${query}`),
    api(`/runs?status=succeeded&limit=1${robot ? `&robot_id=${robot.id}` : ""}`),
    api(`/runs?status=running&limit=1${robot ? `&robot_id=${robot.id}` : ""}`),
  ]);
  return { robot, commands: groupCommands(clips).filter((c) => c.named), views: views.length, stats, succeeded: succeeded.length, running: unfinished.length };
}

function steps(state) {
  const { robot, commands, stats } = state;
  const admin = me.role === "admin";
  const wanted = Math.max(targetCount(robot), 1);
  const twice = commands.filter((c) => c.clips.length >= TIMES_EACH);
  const missing = commands.filter((c) => c.clips.length < TIMES_EACH).map((c) => `“${c.name}”`);
  return [
    {
      title: "Add a robot",
      done: Boolean(robot),
      href: admin ? "/admin" : null,
      text: robot
        ? `${targetsSentence(robot)}`
        : admin ? "Nothing works without one: add a robot on the Admin page (a simulated Kuka arm is a good start)." : "An admin of your household adds the robot on the Admin page: ask them to.",
      link: "Add a robot",
    },
    {
      title: "Record each command twice",
      done: twice.length >= wanted,
      href: "/record",
      text: commands.length
        ? `${twice.length} of ${wanted} commands recorded at least twice` +
          (missing.length ? `; record ${missing.join(", ")} again` : "") +
          (twice.length < wanted ? `; ${robot ? robot.name : "the robot"} knows ${wanted} targets, so give each one a command.` : ".")
        : `No commands yet: on the Record page, say one command per target (${wanted} in all), each ${TIMES_EACH} times or more.`,
      link: "Record",
    },
    {
      title: "Capture camera views",
      done: state.views > 0,
      href: "/label",
      text: state.views > 0 ? "The robot has camera views to ask you about." : robot ? `No camera views of ${robot.name} yet: on the Label page, press “Capture more views”.` : "Add a robot first.",
      link: "Capture views",
    },
    {
      title: "Label: does the command match what the robot sees?",
      done: stats.triplets > 0,
      href: "/label",
      text: stats.labels
        ? `${stats.labels} answers so far, giving ${stats.triplets} usable triplets. A first training run needs a few dozen.`
        : "No answers yet: on the Label page, listen to a command, look at the view and press It is (Y) or It is not (N).",
      link: "Label",
    },
    {
      title: "Train",
      done: state.succeeded > 0,
      href: admin ? "/admin" : "/progress",
      text: state.succeeded
        ? "A training run has finished: see what it changed on the Progress page."
        : state.running ? "A training run is under way: follow it on the Progress page." : admin ? "Start a quick fine-tune on the Admin page, then follow it on the Progress page." : "An admin starts training on the Admin page; you can follow it on the Progress page.",
      link: admin ? "Train" : "Progress",
    },
  ];
}

function draw(list) {
  const checklist = $("checklist");
  checklist.replaceChildren(
    ...list.map((step, index) =>
      element("li", { "data-done": String(step.done), "data-step": String(index + 1) },
        element("span", { class: "tick", "aria-hidden": "true", text: step.done ? "✓" : String(index + 1) }),
        element("div", {},
          element("h3", {}, step.title, element("span", { class: "sr-only", text: step.done ? " (done)" : " (to do)" })),
          element("p", { class: "muted", text: step.text }),
          step.href && !step.done ? element("a", { href: step.href, text: `${step.link} →` }) : ""))),
  );
  const next = list.findIndex((step) => !step.done);
  if (next < 0) say($("next-step"), "Every step is done. Keep recording and labelling now and then, and retrain: each run is compared with the version in use.", "ok");
  else say($("next-step"), `Next: step ${next + 1}, ${list[next].title.split(":")[0].toLowerCase()}.`);
}

async function refresh() {
  draw(steps(await householdState(picker.current())));
}

async function main() {
  ({ me } = await startPage(""));
  picker = await robotPicker($("robot"), refresh);
  $("robot-row").hidden = picker.robots.length < 2;
  pageReady();
  await refresh();
  document.body.dataset.checked = "true";
}

main().catch(pageFailed);
