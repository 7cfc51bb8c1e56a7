// The smart-home VA's holiday policy (apps/reference_agents/priv/home.rules,
// policy holiday; docs/scenarios.md), as a Jason agent embodied through
// EVATAR with the body apps/bil/priv/examples/smart_home_va.xml. Percepts and
// actions are those of org.evatar.jason.EvatarAgent:
//   sensor(Emulator, Type, [param(Name, Value)...], Time)   sensor data
//   feedback(Tag, Type, ok|progress|timeout|failed(Code), Params)
//   emulator(Emulator, Category, Type, Params)   what the body can ask for
//   request(Tag, Type, Filter, Params)            an action: a BIL request

// The house looks inhabited in the evening: lights only when it is dark.
schedule("18:00", if_dark, light("living", on)).
schedule("19:10", if_dark, light("kitchen", on)).
schedule("19:40", if_dark, light("kitchen", off)).
schedule("20:30", if_dark, light("bedroom", on)).
schedule("20:30", if_dark, light("living", off)).
schedule("22:00", always, light(all, off)).

intruder_window(120000).   // ms: motion and a wrong code this close mean an intruder

// ---------------------------------------------------------------- time of day

// The time sensor reports every simulated minute (HH:MM, zero-padded, so
// strings compare in time order); readings may skip minutes when the clock
// runs fast, so every scheduled time passed over since the last reading runs.
+sensor(_, "TimeOfDay", Ps, _) : .member(param("TimeOfDay", Now), Ps)
   <- !time_passes(Now, Ps).

@time[atomic]
+!time_passes(Now, Ps) : last_time(Last) & Now > Last
   <- -+last_time(Now);
      !dark_from(Ps);
      for (schedule(At, Cond, Act) & At > Last & At <= Now) {
         !scheduled(At, Cond, Act)
      }.
@first_time[atomic]
+!time_passes(Now, Ps) : not last_time(_)
   <- +last_time(Now);
      !dark_from(Ps);
      for (schedule(Now, Cond, Act)) {
         !scheduled(Now, Cond, Act)
      }.
+!time_passes(_, _).

+!dark_from(Ps) : .member(param("Dark", "yes"), Ps) <- +dark.
+!dark_from(Ps) <- -dark.

+!scheduled(At, if_dark, Act) : dark <- .print("policy holiday at ", At, " if dark do ", Act); !Act.
+!scheduled(At, if_dark, Act) <- .print("policy holiday at ", At, ": not dark, nothing to do").
+!scheduled(At, always, Act) <- .print("policy holiday at ", At, " do ", Act); !Act.

// ---------------------------------------------------------------- lights

+!light(all, State)
   <- for (emulator(_, _, T, F) & (T == "TurnLightOn" | T == "SwitchSocketOn") & .member(param("Room", R), F)) {
         !light(R, State)
      }.
+!light(Room, on) : emulator(_, _, "TurnLightOn", F) & .member(param("Room", Room), F)
   <- request(light(Room, on), "TurnLightOn", [param("Room", Room)], []).
+!light(Room, off) : emulator(_, _, "TurnLightOff", F) & .member(param("Room", Room), F)
   <- request(light(Room, off), "TurnLightOff", [param("Room", Room)], []).
+!light(Room, on) <- request(light(Room, on), "SwitchSocketOn", [param("Room", Room)], []).
+!light(Room, off) <- request(light(Room, off), "SwitchSocketOff", [param("Room", Room)], []).

+feedback(light(Room, State), _, ok, _) <- -+light_state(Room, State).

// ---------------------------------------------------------------- activities

// Simple activities from the sensor emulators.
+sensor(_, "PasswordInput", Ps, T) : .member(param("WrongPassword", "yes"), Ps)
   <- .print("activity failed_authorisation");
      +failed_authorisation(T);
      !recognise.
+sensor(_, "PasswordInput", Ps, _) : .member(param("WrongPassword", "no"), Ps)
   <- .print("activity authorisation: the right code");
      .abolish(failed_authorisation(_));
      .abolish(motion_at(_, _)).
+sensor(_, "MotionDetected", Ps, T) : .member(param("Motion", "yes"), Ps) & .member(param("Room", R), Ps)
   <- +motion_at(R, T);
      !recognise.

// The complex activity: motion and a failed authorisation close together,
// unless the right code came (which forgets both). Its parts are used up.
@recognise[atomic]
+!recognise : failed_authorisation(TF) & motion_at(R, TM) & intruder_window(W) & math.abs(TM - TF) <= W
   <- .abolish(failed_authorisation(_));
      .abolish(motion_at(_, _));
      .print("complex activity intruder in ", R);
      +intruder(R);
      !protect(R).
+!recognise.

// ---------------------------------------------------------------- the intruder

// The photos are taken by the camera of the intruder's room, or else by
// another camera of the body: a motion seen in a room without one (the
// intruder walked on) must not cost the e-mail.
+!protect(Room) : emulator(_, _, "TakePhoto", F) & .member(param("Room", Room), F)
   <- !protect(Room, Room).
+!protect(Room) : emulator(_, _, "TakePhoto", F) & .member(param("Room", Camera), F)
   <- !protect(Room, Camera).
+!protect(Room, Camera)
   <- .print("policy holiday on intruder do photos 3, email \"INTRUSION\" with photos, alarm, say");
      request(photos(Room), "TakePhoto", [param("Room", Camera)], [param("Count", 3), param("Interval", 1000)]);
      request(alarm, "PlaySound", [], [param("Sound", "alarm"), param("Volume", 100), param("Duration", 3000)]);
      request(say, "PlayVoiceMessage", [],
              [param("Message", "You are being recorded. The police have been called."), param("Volume", 100)]).

// The e-mail waits for its photos.
+feedback(photos(Room), _, ok, Ps) : .member(param("Photos", Ids), Ps)
   <- .print("camera: photos taken: ", Ids);
      .concat("INTRUSION: intruder in ", Room, ". Photos attached.", Body);
      request(email, "SendEmail", [], [param("Subject", "INTRUSION"), param("Body", Body), param("Attachment", Ids)]).
+feedback(photos(Room), _, Failed, _) : Failed \== ok & Failed \== progress
   <- .print("camera failed (", Failed, "): the e-mail goes without photos");
      request(email, "SendEmail", [], [param("Subject", "INTRUSION"),
                                        param("Body", "INTRUSION: intruder. The camera failed.")]).
+feedback(email, _, ok, Ps) : .member(param("File", F), Ps)
   <- .print("e-mail written to ", F);
      +email_written(F).
+feedback(Tag, Type, failed(Code), _) <- .print(Type, " FAILED: ", Code, "; the policy carries on").
+feedback(Tag, Type, timeout, _) <- .print(Type, " timed out; the policy carries on").
+feedback(_, _, _, _).
