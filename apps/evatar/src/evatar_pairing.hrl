%% The state of an evatar_pairing process (private to it and
%% evatar_pairing_effects, which executes the effects on it).
-record(data, {id :: evatar:pairing_id(),
               config :: evatar_pairing_logic:config(),
               mode :: evatar_pairing:mode(),
               %% The role, the rules and the output commit: pure.
               inst :: evatar_ha_instance:state(),
               pids = #{} :: #{binary() => {pid(), reference()}},
               refs = #{} :: #{reference() => binary()},
               timers = #{} :: #{evatar_pairing_logic:timer_key() | {ha, atom()} => reference()},
               %% The monitors of the other instance.
               mons = #{} :: #{active | standby => reference()},
               %% The stall generation this active began serving at; after a
               %% pause, inspections wait for the reconfirmation.
               gen = 0 :: non_neg_integer(),
               inspects = [] :: [{gen_statem:from(), atom()}],
               %% Standby: resumes held until it takes over or hears its active.
               held = [] :: [evatar_ha_role_machine:held(gen_statem:from())],
               %% The live tail's watchers (evatar_tap): [] costs nothing.
               watchers = [] :: [evatar_tap:watcher()],
               %% This pairing's own counters once active here (evatar_metrics).
               metrics = undefined :: evatar_metrics:pairing_ref()}).

