%% @doc Public API of the reference Virtual Agents: Erlang VAs that join
%% EVATAR through agent_bridge_client as any multi-agent system would, with
%% sensor and actuator emulators built from their BIL body and an
%% Observe-Choose-Act cycle around a pure mind (docs/scenarios.md). Also the
%% paper's two scenarios, runnable on avatar_sim's simulated clock, and the
%% rules file of the smart-home VAs (docs/rules.md).
-module(reference_agents).

-export([start_va/1, stop_va/1, inspect/1, tell/3, introduce/2]).
-export([parse_rules/1, rules_error/2]).
-export([holiday/1, robots/1, rooms/1]).

%% @doc Starts a VA linked to the caller (see reference_agents_va:opts()):
%% its name, its mind (a `reference_agents_mind' module and its arguments),
%% its body (a bil:description(), or `none' for a VA without an Avatar),
%% and for an embodied VA the bridge endpoints, the pairing and the
%% credential. The caller receives `{reference_agents, Name, Term}' for
%% each `{notify, Term}' the mind chooses.
-spec start_va(reference_agents_va:opts()) -> {ok, pid()}.
start_va(Opts) -> reference_agents_va:start_link(Opts).

%% @doc Says Bye to EVATAR and stops the VA.
-spec stop_va(pid()) -> ok.
stop_va(Va) -> reference_agents_va:stop(Va).

%% @doc The VA's state (connecting, observing, testing, embodied or
%% unembodied), its last embodiment report, what its mind shows, and the
%% states it went through.
-spec inspect(pid()) -> map().
inspect(Va) -> reference_agents_va:inspect(Va).

%% @doc A MAS message to a VA, from the VA named `From'.
-spec tell(pid(), binary(), term()) -> ok.
tell(Va, From, Message) -> reference_agents_va:tell(Va, From, Message).

%% @doc Tells a VA the pids of the other VAs it talks to, by name.
-spec introduce(pid(), #{binary() => pid()}) -> ok.
introduce(Va, Peers) -> reference_agents_va:introduce(Va, Peers).

%% @doc Reads a rules file (docs/rules.md).
-spec parse_rules(file:filename_all()) ->
          {ok, reference_agents_rules:rules()}
        | {error, reference_agents_rules:error() | {file, term()}}.
parse_rules(File) -> reference_agents_rules:parse_file(File).

%% @doc `File:Line: what is wrong', for a person.
-spec rules_error(file:filename_all(), reference_agents_rules:error() | {file, term()}) -> binary().
rules_error(File, Error) -> reference_agents_rules:format_error(File, Error).

%% @doc Runs the smart-home scenario with one house VA (holiday policy and
%% an intrusion by default) and returns what happened.
-spec holiday(reference_agents_holiday:opts()) -> {ok, map()} | {error, term()}.
holiday(Opts) -> reference_agents_holiday:run(Opts).

%% @doc Runs the collaborative robots scenario to its end.
-spec robots(reference_agents_lego_scenario:opts()) -> {ok, map()} | {error, term()}.
robots(Opts) -> reference_agents_lego_scenario:run(Opts).

%% @doc Runs the one-VA-per-room light control scenario until `until'
%% (16:45 by default) and returns what happened.
-spec rooms(reference_agents_rooms:opts()) -> {ok, map()} | {error, term()}.
rooms(Opts) ->
    case reference_agents_rooms:start(maps:remove(until, Opts)) of
        {ok, S} ->
            try
                ok = reference_agents_rooms:run_until(S, maps:get(until, Opts, "16:45")),
                {ok, reference_agents_rooms:outcome(S)}
            after
                reference_agents_rooms:stop(S)
            end;
        {error, _} = E -> E
    end.
