%% @doc Public API of the WoT Avatar: a W3C Web of Things Thing (its Thing
%% Description, TD 1.1, and the TD's HTTP forms) embodied as an EVATAR
%% Avatar. docs/wot.md section 6 is the guide; every other wot_avatar_*
%% module is internal.
-module(wot_avatar).

-export([describe/2, limits/0]).

-export_type([opts/0, problem/0]).

-type opts() :: #{entity_id := binary(), component => binary(), room => binary(),
                  api_name => binary(), poll_ms => non_neg_integer(),
                  source_url => binary(), allowed_hosts => [binary()],
                  max_size => pos_integer(), max_affordances => pos_integer()}.
%% Every problem has `what' (an atom from a fixed set) and `message' (a
%% sentence); most have `affordance' (the TD's name of it, made printable).
-type problem() :: wot_avatar_td:problem().

%% @doc The BIL description a TD text gives its Avatar, the routes of its
%% services and streams to the Thing's forms, and the problems of what was
%% left out; `{error, Problems}' for a text that is no TD (not JSON, over
%% the limits, no title or security).
-spec describe(binary(), opts()) ->
          {ok, bil:description(), wot_avatar_generate:routes(), [problem()]} | {error, [problem()]}.
describe(Text, Opts) ->
    case wot_avatar_td:read(Text, maps:with([source_url, allowed_hosts, max_size, max_affordances], Opts)) of
        {ok, Thing, P1} ->
            case wot_avatar_generate:description(
                   Thing, maps:with([entity_id, component, room, api_name, poll_ms], Opts)) of
                {ok, D, Routes, P2} -> {ok, D, Routes, P1 ++ P2};
                {error, P2} -> {error, P1 ++ P2}
            end;
        {error, _} = Error ->
            Error
    end.

%% @doc The limits on a TD (defaults, and the largest max_size) and the
%% default polling interval.
-spec limits() -> #{atom() => pos_integer()}.
limits() ->
    (wot_avatar_td:limits())#{poll_ms => wot_avatar_generate:default_poll_ms()}.
