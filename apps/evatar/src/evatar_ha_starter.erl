%% @doc Internal. Starts the standbys that other nodes' actives place on
%% this node (`{start_standby, ...}' of `evatar_ha_proto_v1', handed on by
%% `evatar_cluster'), one at a time, so that two requests for one pairing
%% never both start it: the second finds the first and is told of the
%% active instead. Starting a pairing's tree waits for its init; after a
%% takeover storm hundreds are placed here at once, and this is the
%% process that waits for them, not the membership process.
-module(evatar_ha_starter).
-behaviour(gen_server).

-export([start_link/0]).
-export([init/1, handle_call/3, handle_cast/2, handle_info/2]).

%% @doc Starts the starter, registered as `evatar_ha_starter'.
-spec start_link() -> {ok, pid()} | {error, term()}.
start_link() ->
    gen_server:start_link({local, ?MODULE}, ?MODULE, [], []).

%% @private
-spec init([]) -> {ok, no_state}.
init([]) ->
    {ok, no_state}.

%% @private
-spec handle_call(term(), gen_server:from(), no_state) -> {reply, term(), no_state}.
handle_call(_Request, _From, S) ->
    {reply, {error, unknown_call}, S}.

%% @private
-spec handle_cast(term(), no_state) -> {noreply, no_state}.
handle_cast(_Msg, S) ->
    {noreply, S}.

%% @private
-spec handle_info(term(), no_state) -> {noreply, no_state}.
handle_info({evatar_ha, 1, {start_standby, Id, Config, Active, Epoch}}, S) ->
    ok = start_standby(Id, Config, Active, Epoch),
    {noreply, S};
handle_info(_Msg, S) ->
    {noreply, S}.

start_standby(Id, Config, Active, Epoch) when is_binary(Id), is_pid(Active) ->
    case evatar_registry:whereis_name(Id) of
        undefined ->
            case evatar_pairings_sup:start_pairing(Id, Config, {standby_for, Active}) of
                {ok, _} -> ok;
                {error, Reason} ->
                    logger:notice(#{what => standby_not_started, pairing => Id,
                                    reason => Reason}),
                    ok
            end;
        Local ->
            evatar_ha_proto_v1:peer_instance(Local, {Active, active, Epoch})
    end;
start_standby(_Id, _Config, _Active, _Epoch) ->
    ok.
