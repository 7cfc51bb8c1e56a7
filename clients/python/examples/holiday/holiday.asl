// The smart-home holiday policy (docs/rules.md, apps/reference_agents/priv/home.rules)
// as an AgentSpeak agent embodied through EVATAR (evatar.bdi): nobody is home,
// the lights follow an evening schedule when it is dark, and an intruder (a wrong
// code at the door, then motion in the hall within two minutes) is photographed,
// reported by e-mail with the photos, and met with the alarm and a spoken warning.
//
// Percepts: reading(Component, Type, Params, Time), feedback(Tag, Service, Params),
// failure(Tag, Service, Code), bound(Component). Actions: .request, .minute, .log.

// The schedule: at HH:MM, room, on/off, under which condition.
schedule("18:00", living, on, dark).
schedule("19:10", kitchen, on, dark).
schedule("19:40", kitchen, off, dark).
schedule("20:30", bedroom, on, dark).
schedule("20:30", living, off, dark).
schedule("22:00", all, off, always).

// The VA's light emulators (smart_home_va.xml): room, emulator, on, off.
light("living", living, "LivingLightEmulator01", "TurnLightOn", "TurnLightOff").
light("kitchen", kitchen, "KitchenLightEmulator01", "TurnLightOn", "TurnLightOff").
light("bedroom", bedroom, "LampEmulator01", "SwitchSocketOn", "SwitchSocketOff").

// The complex activity "intruder": motion and a failed authorisation within
// this many ms of the house's clock (2 min), unless a right code was typed in
// between; once recognised, not again within the window.
window(120000).

// ---------------------------------------------------------------- the clock

// Each TimeOfDay reading: the rules whose time the clock passed since the
// previous reading fire (the first reading only sets the clock).
+reading(_, "TimeOfDay", Ps, _)
    : .member(p("TimeOfDay", T), Ps) & .member(p("Dark", D), Ps) <-
    .minute(T, M);
    !tick(M, D).

+!tick(M, D) : now(L) & M > L <-
    -+now(M);
    for (schedule(At, Room, State, Cond)) {
        .minute(At, A);
        if (A > L & A <= M & (Cond == always | D == "yes")) {
            .log("policy holiday at ", At, " do light ", Room, " ", State);
            !switch(Room, State)
        }
    }.
+!tick(M, _) : now(_) <- -+now(M).
+!tick(M, _) <- +now(M).

+!switch(all, State) <-
    for (light(_, Room, _, _, _)) { !switch(Room, State) }.
+!switch(Room, on) : light(_, Room, E, On, _) <- .request(E, On, [], switched(Room, on)).
+!switch(Room, off) : light(_, Room, E, _, Off) <- .request(E, Off, [], switched(Room, off)).

+feedback(switched(Room, State), _, Ps) : .member(p("Changed", C), Ps) <-
    .log("light ", Room, " ", State, " (changed ", C, ")").

// ------------------------------------------------------------- the intruder

+reading(_, "PasswordInput", Ps, T) : .member(p("WrongPassword", "yes"), Ps) <-
    .log("activity failed_authorisation in hall");
    +failed_authorisation(T);
    !recognise(T).
+reading(_, "PasswordInput", Ps, T) : .member(p("WrongPassword", "no"), Ps) <-
    +authorisation(T).
+reading(_, "MotionDetected", Ps, T)
    : .member(p("Motion", "yes"), Ps) & .member(p("Room", Room), Ps) <-
    +motion(T, Room);
    !recognise(T).

+!recognise(T)
    : window(W) & failed_authorisation(F) & F <= T & T - F <= W
      & motion(M, Room) & M <= T & T - M <= W
      & not (authorisation(A) & A >= F)
      & not (intruder(I) & T - I < W) <-
    +intruder(T);
    .log("complex activity intruder in ", Room);
    !respond(Room).
+!recognise(_).

// policy holiday on intruder do photos 3, email "INTRUSION" with photos,
// alarm, say "You are being recorded. The police have been called."
+!respond(Room) <-
    .log("policy holiday on intruder do photos 3");
    .request("CameraEmulator01", "TakePhoto", [p("Count", 3), p("Interval", 1000)], photos(Room)).

+feedback(photos(Room), _, Ps) : .member(p("Photos", Ids), Ps) <-
    .log("camera: photos ", Ids);
    .request("NotifierEmulator01", "SendEmail",
             [p("Subject", "INTRUSION"),
              p("Body", "INTRUSION: intruder in the hall, photos attached"),
              p("Attachment", Ids)], email);
    .request("SpeakerEmulator01", "PlaySound", [p("Sound", "alarm"), p("Volume", 100)], alarm).
+failure(photos(_), _, Code) <-
    .log("camera failed: ", Code);
    .request("SpeakerEmulator01", "PlaySound", [p("Sound", "alarm"), p("Volume", 100)], alarm).

+feedback(email, _, Ps) : .member(p("File", F), Ps) <- .log("e-mail written to ", F).

+feedback(alarm, _, _) <- !say.
+failure(alarm, _, _) <- !say.
+!say <-
    .request("SpeakerEmulator01", "PlayVoiceMessage",
             [p("Message", "You are being recorded. The police have been called."),
              p("Volume", 100)], said).

+failure(Tag, Service, Code) <- .log("failed ", Service, ": ", Code).
